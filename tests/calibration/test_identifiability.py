"""Identifiability (paper section 3.4): eq. 5 sensitivities, the FIM of the Table 3 form,
the profiled rows when the inlet moisture is estimated, correlations, the profile test and the
verdicts. Oracles: independent finite differences, a linear model with known answers, the
Loewner order of information (profiling out a nuisance can only remove information)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from softsensor.calibration.chunked_run import evaluate_parameters, simulate_segments
from softsensor.calibration.dataset import Segment
from softsensor.calibration.disturbance import InletPrior
from softsensor.calibration.identifiability import (
    Sensitivities,
    analyse,
    bounds_prior_sd,
    identify,
    lag1_autocorrelation,
    profile_test,
    sensitivities,
    statistical_fim,
    weighted_fim,
)
from softsensor.calibration.objective import ObjectiveSpec
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES

NS = 1_000_000_000
T0 = 1_767_571_200 * NS


def short_segment(model: DryerModel, hours: float = 4.0, seed: int = 0) -> Segment:
    """Inputs stepping around the nominal point (T_air_in and production), labs hourly."""
    rng = np.random.default_rng(seed)
    K = int(hours * 6)
    U = np.tile(model.nominal_inputs(), (K, 1))
    U[:, 0] += np.repeat(rng.uniform(-25, 25, K // 6 + 1), 6)[:K]
    U[:, 2] = np.repeat(rng.uniform(4.8, 6.8, K // 6 + 1), 6)[:K]
    Y, _ = model.simulate(U, model.theta0)
    lab_t = T0 + (np.arange(1, int(hours)) * 3600 + 300) * NS
    seg = Segment("synthetic", T0, 600.0, U, np.column_stack([Y[:, :2], np.full(K, np.nan)]),
                  lab_t.astype(np.int64), np.zeros(len(lab_t)), tuple(f"L{i}" for i in
                                                                     range(len(lab_t))))
    lab = simulate_segments(model, [seg], model.theta0)[0].lab[0]
    return Segment(seg.source, T0, 600.0, U, seg.Y, seg.lab_time_ns, lab, seg.lab_id)


def _eq4(config, **kw) -> ObjectiveSpec:
    return ObjectiveSpec(cost="eq4", weights=config.cost.weights(), **kw)


def test_sensitivities_match_independent_forward_differences(model, config):
    seg = short_segment(model, 3.0)
    theta = np.array([0.8, 0.5, 1.3, 1.5, 1.6, 5e-4, 40.0])
    (sens,), ev = sensitivities(model, [seg], theta, _eq4(config))
    assert sens.S.shape == (seg.n_windows, 3, 7) and sens.S_lab.shape == (len(seg.lab_value), 7)
    base = simulate_segments(model, [seg], theta)[0]
    h = 1e-4
    for i in (0, 2, 4, 5):
        up = theta.copy()
        up[i] *= 1 + h
        run = simulate_segments(model, [seg], up)[0]
        fd = (run.Y[0] - base.Y[0]) / h  # theta_i dy/dtheta_i, one-sided
        np.testing.assert_allclose(sens.S[:, :, i], fd, rtol=2e-2, atol=1e-6 * np.abs(fd).max())
        fd_lab = (run.lab[0] - base.lab[0]) / h
        np.testing.assert_allclose(sens.S_lab[:, i], fd_lab, rtol=2e-2, atol=1e-9)
        # with the nominal inlet moisture the rows the cost sees are eq. 5 at the samples
        np.testing.assert_allclose(sens.rows[2][:, i], sens.S_lab[:, i], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(sens.relative[:, 1, 0], sens.S[:, 1, 0] / sens.Y[:, 1].mean())
    assert not ev.failed


def test_each_parameter_has_its_own_column_and_the_fim_a_finite_condition(model, config):
    """The cyclone's mult_C and hm_cyc no longer act as one product (issue 10): the Table 3
    FIM of a varied segment has full rank and a finite condition number."""
    seg = short_segment(model, 4.0, seed=1)
    (sens,), _ = sensitivities(model, [seg], model.theta0, _eq4(config))
    F = weighted_fim([sens], config.cost.weights())
    np.testing.assert_array_equal(F, F.T)
    lam = np.linalg.eigvalsh(F)
    assert lam[0] > 0 and lam[-1] / lam[0] < 1e12
    iC, iH = PARAMETER_NAMES.index("mult_C"), PARAMETER_NAMES.index("hm_cyc")
    a, b = sens.S[:, :, iC].ravel(), sens.S[:, :, iH].ravel()
    assert abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)) < 0.999


def test_profiling_out_the_inlet_moisture_can_only_remove_information(model, config):
    seg = short_segment(model, 6.0, seed=2)
    nominal, _ = sensitivities(model, [seg], model.theta0, _eq4(config))
    spec = _eq4(config, inlet=InletPrior(2.0, 0.1, 0.02))
    profiled, _ = sensitivities(model, [seg], model.theta0, spec)
    noise = np.array([0.1, 0.1, 0.003])
    F_nom = statistical_fim(nominal, noise)
    F_pro = statistical_fim(profiled, noise)
    # no parameter gains information (the trajectory's fit is re-weighted by the residuals,
    # so this is not an exact projection and the Loewner order holds only approximately) ...
    assert np.all(np.diag(F_pro) <= 1.02 * np.diag(F_nom)), np.diag(F_pro) / np.diag(F_nom)
    # ... and mult_D, whose effect on the temperatures a change of load imitates, loses some
    i = PARAMETER_NAMES.index("mult_D")
    assert F_pro[i, i] < 0.9 * F_nom[i, i]


def test_fims_by_hand_on_given_sensitivities(config):
    """The Table 3 form and the statistical FIM from a hand-made Jacobian."""
    K, L = 5, 2
    rng = np.random.default_rng(3)
    S = rng.normal(size=(K, 3, 7))
    S_lab = rng.normal(size=(L, 7))
    Ymeas = np.full((K, 3), 300.0)
    Ymeas[1, 0] = np.nan  # one missing window of T_dryer_out
    seg = Segment("x", T0, 600.0, np.zeros((K, 8)), Ymeas, np.array([T0 + 700 * NS,
                  T0 + 1900 * NS]), np.zeros(L), ("a", "b"))
    J0 = S[[0, 2, 3, 4], 0, :]
    sens = Sensitivities(np.ones(7), np.ones((K, 3)), S, S_lab, [J0, S[:, 1], S_lab], seg)
    w = config.cost.weights()
    expected = w[0] ** 2 * J0.T @ J0 + w[1] ** 2 * S[:, 1].T @ S[:, 1] + w[2] ** 2 * \
        S_lab.T @ S_lab
    np.testing.assert_allclose(weighted_fim([sens], w), expected, rtol=1e-12)
    np.testing.assert_allclose(weighted_fim([sens], w, sigma=2.0), expected / 4, rtol=1e-12)
    noise = np.array([0.5, 0.25, 0.01])
    Fs = statistical_fim([sens], noise)
    exp_s = J0.T @ J0 / 0.25 + S[:, 1].T @ S[:, 1] / 0.0625 + S_lab.T @ S_lab / 1e-4
    np.testing.assert_allclose(Fs, exp_s, rtol=1e-12)
    p_sd = bounds_prior_sd(config.bounds())
    ident = analyse([sens], w, noise, p_sd)
    C = np.linalg.inv(exp_s + np.diag(1 / p_sd ** 2))
    np.testing.assert_allclose([v.relative_se for v in ident.verdicts],
                               np.sqrt(np.diag(C)), rtol=1e-8)
    np.testing.assert_allclose(np.diag(ident.correlation), 1.0)
    assert np.all(np.abs(ident.correlation) <= 1 + 1e-12)
    assert ident.identifiable == []  # without the profile test nothing is vouched for


@dataclass
class LinearModel:
    """y = y0 + sum_i G_i ln(theta_i / theta_ref_i) per window: a model with known answers."""

    G: np.ndarray          # (3, 7)
    theta_ref: np.ndarray  # (7,)
    y0: np.ndarray         # (3,)

    def simulate(self, U, theta, raise_on_failure=True, **_):
        """Outputs of every window; the state is irrelevant (returned as None)."""
        U = np.asarray(U)
        theta = np.atleast_2d(theta)
        z = np.log(theta / self.theta_ref)  # (B, 7)
        Y = self.y0 + z @ self.G.T          # (B, 3)
        shape = (theta.shape[0], U.shape[-2], 3)
        Y = np.broadcast_to(Y[:, None, :], shape).copy()
        Y[..., 0] += np.broadcast_to(U[..., 0] - U[..., 0].mean(), shape[:2])
        return Y, None


def test_profile_test_on_a_linear_model(config):
    """Exactly collinear mult_D/mult_h: moving one is compensated by the other (no rise);
    mult_p has its own signature: under the likelihood its rise at 15 % is half the squared
    move in standard errors of the statistical FIM; untested ones stay NaN."""
    G = np.zeros((3, 7))
    G[:, 0] = [4.0, 3.5, 0.04]   # mult_D
    G[:, 2] = [2.0, 1.75, 0.02]  # mult_h = exactly half of mult_D's effect
    G[:, 4] = [-0.3, -0.6, 0.0]  # mult_p: its own signature
    ref = config.parameter_vector()
    lm = LinearModel(G, ref, np.array([348.0, 346.0, 0.11]))
    K = 96
    U = np.zeros((K, 8))
    U[:, 0] = np.sin(np.arange(K))
    Y_true, _ = lm.simulate(U, ref)
    meas = Y_true[0].copy()
    # zero-mean noise orthogonal to the constant shifts parameters cause: ``ref`` is the
    # exact minimum and the residuals' RMSE is their noise
    meas[:, :2] += 0.1 * np.where(np.arange(K) % 2, 1.0, -1.0)[:, None]
    meas[:, 2] = np.nan
    lab_t = T0 + (np.arange(8) * 12 + 3) * 600 * NS
    seg = Segment("lin", T0, 600.0, U, meas, lab_t.astype(np.int64),
                  0.11 + 0.003 * np.array([1.0, -1.0] * 4), tuple("abcdefgh"))
    spec = ObjectiveSpec(cost="likelihood", weights=config.cost.weights())
    (sens,), ev = sensitivities(lm, [seg], ref, spec)
    np.testing.assert_allclose(sens.S[:, :, 0], np.broadcast_to(G[:, 0], (K, 3)), rtol=1e-6)
    tested = np.zeros(7, dtype=bool)
    tested[[0, 2, 4]] = True
    prof = profile_test(lm, [seg], ref, ev, spec, config.bounds(), tested, tested)
    assert np.isnan(prof.rise_up[[1, 3, 5, 6]]).all()
    # compensated (to what three Gauss-Newton steps reach): far below the 2 that would pin it
    assert abs(prof.rise(0)) < 0.1 and abs(prof.rise(2)) < 0.1
    noise = np.array([0.1, 0.1, 0.003])
    rows = [sens.channel_rows(c)[:, [0, 2, 4]] for c in range(3)]
    F = sum(r.T @ r / noise[c] ** 2 for c, r in enumerate(rows))
    s_p = np.sqrt(np.linalg.pinv(F)[2, 2])
    # N/2 ln(MSE) rises by at most chi2/2 (the logarithm saturates for a large move), i.e. by
    # at most (ln(1.15) / s)^2 / 2 on the smaller side, and by much more than nothing
    chi2_half = 0.5 * (np.log(1.15) / s_p) ** 2
    assert 0.5 * chi2_half < prof.rise(4) <= 1.02 * chi2_half, (prof.rise(4), chi2_half)
    p_sd = bounds_prior_sd(config.bounds())
    ident = analyse([sens], config.cost.weights(), noise, p_sd, prof)
    assert ident.verdict("mult_D").verdict == "weakly identifiable"
    assert "mult_h" in ident.verdict("mult_D").reason
    assert ident.verdict("mult_k").verdict == "not identifiable"
    assert (ident.verdict("mult_p").verdict == "identifiable") == (
        s_p <= 0.075 and prof.rise(4) >= 2.0)


def test_identify_on_the_model_names_every_parameter_once(model, config):
    seg = short_segment(model, 4.0, seed=4)
    spec = dataclasses.replace(_eq4(config), prior_center=np.log(model.theta0))
    ident, sens = identify(model, [seg], model.theta0, spec, config.bounds(), profile=False)
    assert [v.name for v in ident.verdicts] == list(PARAMETER_NAMES)
    assert np.isfinite(ident.condition_number) and ident.condition_number > 1
    assert len(sens) == 1 and sens[0].rows[0].shape[1] == 7
    ev = evaluate_parameters(model, [seg], model.theta0, spec)[0]
    assert ev.prior == 0.0  # at the prior's centre


def test_lag1_autocorrelation_of_an_ar1_series():
    rng = np.random.default_rng(5)
    e = rng.normal(size=20000)
    x = np.empty_like(e)
    x[0] = e[0]
    for k in range(1, len(e)):
        x[k] = 0.6 * x[k - 1] + e[k]
    assert lag1_autocorrelation(x) == pytest.approx(0.6, abs=0.02)
    assert abs(lag1_autocorrelation(e)) < 0.03
    assert lag1_autocorrelation(np.array([1.0, np.nan])) == 0.0


def test_importance_ranks_the_parameters_a_cost_depends_on():
    # a study whose cost depends on mult_D and mult_h only: both evaluators must say so, and
    # the default (PED-ANOVA) must rank them first
    import optuna

    from softsensor.calibration.identifiability import parameter_importance
    from softsensor.errors import ConfigError
    from softsensor.plantconfig import PARAMETER_NAMES

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(sampler=optuna.samplers.TPESampler(seed=0))

    def cost(trial):
        x = {n: trial.suggest_float(n, 0.01, 5.0, log=True) for n in PARAMETER_NAMES}
        return (np.log(x["mult_D"]) - 0.2) ** 2 + 0.3 * np.log(x["mult_h"]) ** 2

    study.optimize(cost, n_trials=120)
    ped = parameter_importance(study)
    assert ped == parameter_importance(study)  # deterministic
    assert set(sorted(ped, key=ped.get)[-2:]) == {"mult_D", "mult_h"}
    fan = parameter_importance(study, "fanova")  # offered; see its docstring for its bias
    assert set(fan) == set(PARAMETER_NAMES) and sum(fan.values()) == pytest.approx(1.0)
    with pytest.raises(ConfigError, match="unknown importance method"):
        parameter_importance(study, "gini")
