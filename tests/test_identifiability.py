"""Identifiability (paper section 3.4): eq. 5 sensitivities, the FIM of the Table 3 form,
correlations, verdicts. Oracles: independent finite differences, a linear model, the exact
product structure mult_C * hm_cyc of the cyclone evaporation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from softsensor.calibration.chunked_run import simulate_segments
from softsensor.calibration.cost import evaluate_fit
from softsensor.calibration.dataset import Segment
from softsensor.calibration.identifiability import (
    Sensitivities,
    analyse,
    displacement_test,
    eq4_weights,
    lag1_autocorrelation,
    prior_sd,
    sensitivities,
    statistical_fim,
    weighted_fim,
)
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


def test_sensitivities_match_independent_forward_differences(model):
    seg = short_segment(model, 3.0)
    theta = np.array([0.8, 3.0, 1.3, 1.5, 1.6, 5e-4, 40.0])
    sens = sensitivities(model, seg, theta)
    assert sens.S.shape == (seg.n_windows, 3, 7) and sens.S_lab.shape == (len(seg.lab_value), 7)
    h = 1e-4
    for i in (0, 2, 4, 5):
        up = theta.copy()
        up[i] *= 1 + h
        Y1, _ = model.simulate(seg.U, up)
        fd = (Y1 - sens.Y) / h  # theta_i dy/dtheta_i, one-sided
        np.testing.assert_allclose(sens.S[:, :, i], fd, rtol=2e-2, atol=1e-6 * np.abs(fd).max())
        lab1 = simulate_segments(model, [seg], up)[0].lab[0]
        fd_lab = (lab1 - sens.lab) / h
        np.testing.assert_allclose(sens.S_lab[:, i], fd_lab, rtol=2e-2, atol=1e-9)
    # relative sensitivities are S / mean(y)
    np.testing.assert_allclose(sens.relative[:, 1, 0], sens.S[:, 1, 0] / sens.Y[:, 1].mean())


def test_cyclone_product_makes_the_fim_singular_but_symmetric_psd(model, config):
    """mult_C and hm_cyc act only through their product: identical eq. 5 columns, a null
    direction (+1, -1) in ln(theta), correlation -1 and both poorly identifiable."""
    seg = short_segment(model, 4.0, seed=1)
    theta = np.array([1.0, 4.0, 1.0, 1.0, 1.0, 8e-4, 20.0])  # cyclone evaporation visible
    sens = sensitivities(model, seg, theta)
    iC, iH = PARAMETER_NAMES.index("mult_C"), PARAMETER_NAMES.index("hm_cyc")
    assert np.abs(sens.S[:, 2, iC]).max() > 1e-4  # the cyclone dries noticeably
    np.testing.assert_allclose(sens.S[:, :, iC], sens.S[:, :, iH], rtol=1e-4,
                               atol=1e-9)
    F = weighted_fim([sens], config.cost.weights())
    np.testing.assert_array_equal(F, F.T)
    lam, vec = np.linalg.eigh(F)
    assert lam[0] >= -1e-12 * lam[-1]
    null = np.zeros(7)
    null[[iC, iH]] = [1, -1]
    assert np.linalg.norm(F @ null) <= 1e-6 * np.linalg.norm(F) * np.sqrt(2)
    ident = analyse([sens], config.cost.weights(), np.array([0.05, 0.05, 0.002]),
                    config.bounds())
    assert ident.correlation[iC, iH] < -0.9
    assert ident.condition_number > 1e8
    for name in ("mult_C", "hm_cyc"):
        assert ident.verdict(name).verdict != "identifiable"
    assert "mult_C" in ident.weakest_directions(1)[0] and "hm_cyc" in \
        ident.weakest_directions(1)[0]
    # without a displacement test nothing is vouched for
    assert ident.identifiable == []


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
    sens = Sensitivities(np.ones(7), np.ones((K, 3)), S, S_lab, seg)
    w = config.cost.weights()
    J0 = S[[0, 2, 3, 4], 0, :]
    expected = w[0] ** 2 * J0.T @ J0 + w[1] ** 2 * S[:, 1].T @ S[:, 1] + w[2] ** 2 * \
        S_lab.T @ S_lab
    np.testing.assert_allclose(weighted_fim([sens], w), expected, rtol=1e-12)
    np.testing.assert_allclose(weighted_fim([sens], w, sigma=2.0), expected / 4, rtol=1e-12)
    noise = np.array([0.5, 0.25, 0.01])
    Fs = statistical_fim([sens], noise)
    exp_s = J0.T @ J0 / 0.25 + S[:, 1].T @ S[:, 1] / 0.0625 + S_lab.T @ S_lab / 1e-4
    np.testing.assert_allclose(Fs, exp_s, rtol=1e-12)
    ident = analyse([sens], w, noise, config.bounds())
    C = np.linalg.inv(exp_s + np.diag(1 / prior_sd(config.bounds()) ** 2))
    np.testing.assert_allclose([v.relative_se for v in ident.verdicts],
                               np.sqrt(np.diag(C)), rtol=1e-8)
    np.testing.assert_allclose(np.diag(ident.correlation), 1.0)
    assert np.all(np.abs(ident.correlation) <= 1 + 1e-12)


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
        Y = np.broadcast_to(Y[:, None, :], (theta.shape[0], U.shape[-2], 3)).copy()
        Y[..., 0] += U[..., 0] - U[..., 0].mean()  # some variation over time
        return Y, None


def test_displacement_test_on_a_linear_model(config):
    """Exactly collinear mult_D/mult_h: moving one is compensated by the other (no rise);
    mult_p has its own signature: its rise matches the sandwich standard error of the eq. 4
    estimator, z = 0.15 / (2 s); untested ones stay NaN."""
    G = np.zeros((3, 7))
    G[:, 0] = [4.0, 3.5, 0.04]   # mult_D
    G[:, 2] = [2.0, 1.75, 0.02]  # mult_h = exactly half of mult_D's effect
    G[:, 4] = [-0.1, -0.25, 0.0]  # mult_p: small effect, so eq. 4 is near-quadratic at 15 %
    ref = config.parameter_vector()
    lm = LinearModel(G, ref, np.array([348.0, 346.0, 0.11]))
    K = 48
    U = np.zeros((K, 8))
    U[:, 0] = np.sin(np.arange(K))
    Y_true, _ = lm.simulate(U, ref)
    meas = Y_true[0].copy()
    # zero-mean noise: orthogonal to the constant shifts parameters cause, so ``ref`` is the
    # exact minimum of eq. 4
    meas[:, :2] += 0.1 * np.where(np.arange(K) % 2, 1.0, -1.0)[:, None]
    meas[:, 2] = np.nan
    lab_t = T0 + (np.arange(4) * 6 + 3) * 600 * NS
    seg = Segment("lin", T0, 600.0, U, meas, lab_t.astype(np.int64),
                  0.11 + 0.003 * np.array([1.0, -1.0, 1.0, -1.0]), tuple("abcd"))
    sens = sensitivities(lm, seg, ref)
    np.testing.assert_allclose(sens.S[:, :, 0], np.broadcast_to(G[:, 0], (K, 3)), rtol=1e-6)
    run_fit = simulate_segments(lm, [seg], ref)[0]
    fit = evaluate_fit([run_fit], [seg], config.cost.weights())[0]
    noise = np.array([0.1, 0.1, 0.003])
    tested = np.zeros(7, dtype=bool)
    tested[[0, 2, 4]] = True
    disp = displacement_test(lm, [seg], ref, [sens], fit, [run_fit], config.cost.weights(),
                             noise, config.bounds(), tested)
    assert np.isnan(disp.z_up[[1, 3, 5, 6]]).all()
    assert abs(disp.z(0)) < 1e-6 and abs(disp.z(2)) < 1e-6  # compensated exactly
    # sandwich standard error of mult_p with mult_D, mult_h free (pinv: they are collinear)
    a = eq4_weights(fit, config.cost.weights())
    rows = [sens.channel_rows(c)[:, [0, 2, 4]] for c in range(3)]
    H = sum(a[c] * r.T @ r for c, r in enumerate(rows))
    Gm = sum((a[c] * noise[c]) ** 2 * r.T @ r for c, r in enumerate(rows))
    Hi = np.linalg.pinv(H)
    s_p = np.sqrt((Hi @ Gm @ Hi)[2, 2])
    assert disp.z(4) == pytest.approx(0.15 / (2 * s_p), rel=0.15)  # sqrt in eq. 4: ~quadratic
    ident = analyse([sens], config.cost.weights(), noise, config.bounds(), disp)
    assert ident.verdict("mult_p").eq4_se == pytest.approx(s_p, rel=0.15)
    expected = ["mult_p"] if s_p <= 0.05 else []
    assert ident.identifiable == expected
    assert ident.verdict("mult_D").verdict == "weakly identifiable"
    assert "mult_h" in ident.verdict("mult_D").reason
    assert ident.verdict("mult_k").verdict == "not identifiable"


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
