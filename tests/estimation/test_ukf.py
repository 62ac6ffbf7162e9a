"""The UKF virtual sensor on a linear plant: oracle, late labs, robustness, health, restart.

A linear stand-in for the dryer model (:class:`LinearDryer`, derivatives of ``DryerModel`` at
the nominal point) makes every test fast and lets a plain linear Kalman filter serve as the
oracle: for linear models the unscented transform is exact, so the UKF must reproduce the KF to
round-off (filterpy's own test idea, STYLE.md). The tests on virtual-plant days with the real
model are in ``tests/estimation/test_ukf_virtual_plant.py``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
from filterpy.kalman import predict as kf_predict

from softsensor.errors import ConfigError, EstimationError, IngestError
from softsensor.estimation.consistency import Innovation, chi_square_test
from softsensor.estimation.interface import LabResult, Window
from softsensor.estimation.settings import EstimatorSettings, estimator_settings
from softsensor.estimation.state_space import (
    STATE_NAMES,
    X_BIAS,
    X_HEAT,
    X_IN,
    ErrorPriors,
    InletTransform,
)
from softsensor.estimation.tick_history import FilterState
from softsensor.estimation.ukf import UkfEstimator
from softsensor.estimation.ukf_step import TickData, measurements, transient_variance
from softsensor.plantconfig import load_plant_config
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.inputs import InputHold

W_NS = 600 * 10**9
T0_NS = 1_767_571_200_000_000_000
CFG = load_plant_config()

#: d(T_dryer_out, T_cyclone_out, moisture_out) / d(moisture_in, T_air_in) near the nominal point
#: of dryer1 (the real model: -28 K, 0.32 K/K; moisture 0.63, -0.003 per K).
A = np.array([[-28.0, 0.32], [-27.0, 0.31], [0.63, -0.0031]])
Y0 = np.array([347.8, 346.4, 0.10])
U0 = CFG.nominal


class LinearDryer:
    """Linear stand-in for ``DryerModel`` with the same call signatures (one dummy wall state).

    ``mo_offset`` shifts the outlet moisture and ``T_offset`` both outlet temperatures (a plant
    whose kinetics or energy balance differ from the model's).
    """

    window = 600.0
    theta0 = CFG.parameter_vector()

    def __init__(self, mo_offset: float = 0.0, T_offset: float = 0.0) -> None:
        self.mo_offset = mo_offset
        self.T_offset = T_offset

    def outputs(self, U: np.ndarray) -> np.ndarray:
        U = np.asarray(U, float)
        dx = U[..., 7] - U0.moisture_in
        dt = U[..., 0] - U0.T_air_in
        y = Y0 + dx[..., None] * A[:, 0] + dt[..., None] * A[:, 1]
        y[..., 2] += self.mo_offset
        y[..., :2] += self.T_offset
        return y

    def steady_state(self, u, theta=None):
        u = np.asarray(u, float)
        return np.full(u.shape[:-1] + (1,), 400.0), self.outputs(u)

    def simulate(self, U, theta=None, aux=None, state0=None, dt=None, raise_on_failure=True):
        U = np.asarray(U, float)
        return self.outputs(U), np.full(U.shape[:-2] + (1,), 400.0)


def window(k: int, T_air_in: float, T_out: tuple[float, float] | None, stale: bool = False,
           **means: float | None) -> Window:
    """Window ``k`` of a test day with nominal inputs except ``T_air_in`` and ``means``."""
    m: dict[str, float | None] = dict.fromkeys(SCAN_SIGNALS, None)
    m.update({n: float(getattr(U0, n)) for n in ("m_air", "m_fiber", "T_fiber_in", "m_steam",
                                                  "T_amb", "H_amb", "T_sp")})
    m.update(T_air_in=T_air_in, flap_cmd=50.0)
    if T_out is not None:
        m.update(T_dryer_out=T_out[0], T_cyclone_out=T_out[1])
    m.update(means)
    return Window(T0_NS + k * W_NS, T0_NS + (k + 1) * W_NS, m, 60,
                  {n: (60 if v is not None else 0) for n, v in m.items()}, stale)


def synthetic_day(n: int, seed: int, x_in=None, T_air_noise: float = 0.25,
                  plant: LinearDryer | None = None):
    """Windows and true outputs of a linear plant whose inlet moisture follows ``x_in(k)``."""
    plant = plant or LinearDryer()
    rng = np.random.default_rng(seed)
    x_in = x_in or (lambda k: 1.0 + 0.05 * math.sin(k / 40.0))
    wins, truth = [], []
    for k in range(n):
        Ta = 485.0 + 5.0 * math.sin(k / 17.0)
        u = np.array([Ta + rng.normal(0, T_air_noise), 82.0, 6.0, 370.0, 0.5, 283.15, 0.006,
                      x_in(k)])
        y = plant.outputs(u)
        meas = y[:2] + rng.normal(0.0, 0.5 / math.sqrt(60.0), 2)
        wins.append(window(k, Ta, (float(meas[0]), float(meas[1]))))
        truth.append((x_in(k), float(y[2])))
    return wins, np.array(truth)


def lab(k: int, value: float, sid: str, delay_ticks: float = 0.0, frac: float = 0.5) -> LabResult:
    """Lab result sampled in window ``k`` (at ``frac`` of it), logged ``delay_ticks`` later."""
    t = T0_NS + k * W_NS + int(frac * W_NS)
    return LabResult(t, value, sid, t + int(delay_ticks * W_NS))


def make(**overrides) -> UkfEstimator:
    """A UKF on the linear model with default settings except ``overrides``."""
    return UkfEstimator(CFG, dataclasses.replace(EstimatorSettings(), **overrides),
                        model=LinearDryer())


#: The linear plant is the model (no model error): priors of a well-calibrated model, whose
#: temperature errors are small enough for the temperatures to show the inlet moisture.
CALIBRATED = {"T_offset_std": 0.2, "T_channel_std": 0.1, "moisture_in_walk": 0.01}
#: No covariance matching, no outlier gate, no noise adaptation: the plain filter.
NO_ADAPT = {"moisture_in_adapt": 1e9, "moisture_out_bias_adapt": 1e9, "lab_gate": 1e9,
            "adapt_limit": 1.0}
#: The filter's physics published alone: no peers weighed beside it, no conformal band
#: (:mod:`softsensor.estimation.peer_blend`, tested in tests/estimation/test_peer_blend.py).
PHYSICS_ONLY = {"peer_blend": False, "band_conformal": False}
#: The inlet gain held at zero, as without a history: the linear Kalman filter is then the
#: oracle (its product with the inlet moisture is not linear).
NO_GAIN = {"inlet_gain_std": 1e-9, "inlet_gain_walk": 0.0}


# ---------------------------------------------------------------------------------- oracle
def test_ukf_equals_linear_kalman_filter_on_a_linear_plant():
    """UKF = KF to round-off (UT exact for linear maps and the soft clip the identity inside
    the range), including the reported moisture_out, offsets and NIS."""
    s = dataclasses.replace(EstimatorSettings(), **NO_ADAPT, **NO_GAIN, **PHYSICS_ONLY)
    est = UkfEstimator(CFG, s, model=LinearDryer())
    wins, truth = synthetic_day(30, seed=3)
    labs = {7: lab(7, truth[7, 1] + 0.004, "L1"), 19: lab(19, truth[19, 1] - 0.003, "L2")}
    pri = ErrorPriors.from_config(CFG, s, float(np.mean(A[:2, 1])))
    a = np.exp(-600.0 / pri.tau)
    r = 600.0 / (s.moisture_in_tau_h * 3600.0)
    F = np.diag(np.r_[math.exp(-r), a])
    Q = np.diag(np.r_[s.walk_per_window(s.moisture_in_walk, 600.0) ** 2
                      * (1 - math.exp(-2 * r)) / (2 * r),
                      np.where(np.isinf(pri.tau), pri.walk**2 * 600.0,
                               pri.sigma**2 * (1 - a**2))])
    x = np.array([CFG.nominal.moisture_in, 0.0, 0.0, 0.0, 0.0, 0.0])
    x_nom = x.copy()
    P = np.diag(np.r_[s.moisture_in_std0**2, pri.sigma**2])
    # rows: T_dryer_out, T_cyclone_out, moisture_out over (X_in, heat input, b_d, b_c, b_m,
    # inlet gain: held at zero, its product with the inlet moisture is not linear)
    Hfull = np.array([[A[0, 0], A[0, 1], 1.0, 0.0, 0.0, 0.0],
                      [A[1, 0], A[1, 1], 0.0, 1.0, 0.0, 0.0],
                      [A[2, 0], A[2, 1], 0.0, 0.0, 1.0, 0.0]])
    r_T = s.temperature_sensor_std**2 / 60 + s.temperature_model_std**2
    r_L = s.lab_std**2 + s.moisture_out_jitter_std**2
    for k, w in enumerate(wins):
        if k in labs:
            est.add_lab(labs[k])            # sampled in this window: applied at its tick
        body = est.tick(w).to_body()
        x, P = F @ x + (np.eye(6) - F) @ x_nom, F @ P @ F.T + Q
        u = np.array([w.means["T_air_in"], 82, 6, 370, 0.5, 283.15, 0.006,
                      CFG.nominal.moisture_in])
        c = LinearDryer().outputs(u) - Hfull[:, 0] * CFG.nominal.moisture_in
        rows = [0, 1] + ([2] if k in labs else [])
        z = np.array([w.means["T_dryer_out"], w.means["T_cyclone_out"]]
                     + ([labs[k].moisture_out] if k in labs else []))
        H = Hfull[rows]
        R = np.diag([r_T, r_T] + ([r_L] if k in labs else []))
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        nu = z - (H @ x + c[rows])
        x, P = x + K @ nu, P - K @ S @ K.T
        assert body["moisture_in"] == pytest.approx(x[0], abs=1e-9)
        assert body["moisture_in_std"] == pytest.approx(math.sqrt(P[0, 0]), rel=1e-7)
        for i, key in ((1, "T_air_in_offset"), (2, "T_dryer_out_offset"),
                       (3, "T_cyclone_out_offset"), (4, "moisture_out_bias")):
            assert body[key] == pytest.approx(x[i], abs=1e-9), key
        mo = Hfull[2] @ x + c[2]
        mo_var = Hfull[2] @ P @ Hfull[2]
        assert body["moisture_out"] == pytest.approx(mo, abs=1e-10)
        assert body["moisture_out_window_std"] == pytest.approx(math.sqrt(mo_var), rel=1e-6)
        assert body["moisture_out_std"] == pytest.approx(
            math.sqrt(mo_var + s.moisture_out_jitter_std**2), rel=1e-6)
        assert body["T_dryer_out_model"] == pytest.approx(Hfull[0] @ x + c[0], abs=1e-8)
        assert body["nis"] == pytest.approx(float(nu @ np.linalg.solve(S, nu)), rel=1e-6)
        assert body["nis_dof"] == len(rows)
        assert not body["fallback"]
    assert np.allclose(est._state.P, P, rtol=1e-6, atol=1e-14)


class CurvedDryer(LinearDryer):
    """:class:`LinearDryer` with outputs curved in the inlet moisture and the heat input, so
    that the unscented transform is no longer exact and the weights of its covariance matter."""

    def outputs(self, U: np.ndarray) -> np.ndarray:
        y = super().outputs(U)
        U = np.asarray(U, float)
        dx = U[..., 7] - U0.moisture_in
        dt = U[..., 0] - U0.T_air_in
        y[..., :2] += (60.0 * dx**2 + 0.05 * dt**2)[..., None]
        y[..., 2] += 0.8 * dx**2
        return y


def test_tick_equals_filterpys_unscented_kalman_filter_with_the_model_in_hx():
    """One tick of a curved model with both temperatures and a lab result: the estimator
    (batched model run over the distinct model inputs, joint unscented transform, Kalman update
    of that Gaussian) gives the posterior, innovation and NIS of filterpy's own
    UnscentedKalmanFilter run on the same prior with the model in ``hx``, one sigma point at a
    time, to round-off."""
    # the inlet gain on (as with a history), so its product with the model is checked too
    s = dataclasses.replace(EstimatorSettings(), offset_adapt=1e9, inlet_gain_std=1.0,
                            **NO_ADAPT)
    model = CurvedDryer()
    est = UkfEstimator(CFG, s, model=model)
    wins, truth = synthetic_day(1, seed=5, plant=model)
    result = lab(0, truth[0, 1] + 0.01, "L1")
    assert est.add_lab(result) is None
    body = est.tick(wins[0]).to_body()
    assert body["labs_applied"] == ["L1"] and body["nis_dof"] == 3
    # the same prior, by filterpy's linear predict
    pri = ErrorPriors.from_config(CFG, s, est.heat_gain)
    a = np.exp(-600.0 / pri.tau)
    r = 600.0 / (s.moisture_in_tau_h * 3600.0)
    F = np.diag(np.r_[math.exp(-r), a])
    Q = np.diag(np.r_[s.walk_per_window(s.moisture_in_walk, 600.0) ** 2
                      * (1 - math.exp(-2 * r)) / (2 * r),
                      np.where(np.isinf(pri.tau), pri.walk**2 * 600.0,
                               pri.sigma**2 * (1 - a**2))])
    x_nom = np.array([CFG.nominal.moisture_in, 0.0, 0.0, 0.0, 0.0, 0.0])
    P0 = np.diag(np.r_[s.moisture_in_std0**2, pri.sigma**2])
    x, P = kf_predict(x_nom, P0, F, Q, u=x_nom, B=np.eye(6) - F)
    u = InputHold(CFG.nominal_inputs()).inputs(wins[0])[0]

    def hx(xs: np.ndarray) -> np.ndarray:
        ui = u.copy()
        ui[7] = est.inlet.forward(xs[0])
        ui[0] += xs[1]
        y = model.outputs(ui)
        # the inlet gain scales the outlet moisture's response from the reference inlet
        # moisture (the nominal, without a history), at the point's own heat input
        ur = u.copy()
        ur[7] = CFG.nominal.moisture_in
        ur[0] += xs[1]
        y_ref = model.outputs(ur)
        return np.array([y[0] + xs[2], y[1] + xs[3],
                         y[2] + xs[5] * (y[2] - y_ref[2]) + xs[4]])

    points = MerweScaledSigmaPoints(6, s.sigma_alpha, s.sigma_beta, s.sigma_kappa)
    ukf = UnscentedKalmanFilter(6, 3, 600.0, hx, lambda xs, dt: xs, points)
    ukf.x, ukf.P, ukf.Q = x, P, np.zeros((6, 6))
    ukf.predict()  # the identity with no noise: sigma points of the prior
    r_T = s.temperature_sensor_std**2 / 60 + s.temperature_model_std**2
    r_L = s.lab_std**2 + s.moisture_out_jitter_std**2
    z = np.array([wins[0].means["T_dryer_out"], wins[0].means["T_cyclone_out"],
                  result.moisture_out])
    ukf.update(z, np.diag([r_T, r_T, r_L]))
    # the model's curvature matters (the predicted temperatures are not the model at the
    # mean) and the measurements move the inlet moisture
    assert np.all(np.abs(points.Wm @ ukf.sigmas_h - hx(x))[:2] > 0.5)
    assert abs(ukf.x[0] - x[0]) > 1e-3
    np.testing.assert_allclose(est._state.x, ukf.x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est._state.P, ukf.P, rtol=1e-8, atol=1e-14)
    assert body["nis"] == pytest.approx(float(ukf.y @ ukf.SI @ ukf.y), rel=1e-9)
    assert body["T_air_in_offset"] == pytest.approx(ukf.x[1], rel=1e-9)


def test_filter_tracks_the_inlet_moisture_of_a_linear_plant():
    """An inlet moisture moving +-0.05 kg/kg over hours, seen by the temperatures alone: the
    filter follows it within 0.01 kg/kg when the model's temperature errors are small, and
    within 0.02 kg/kg with the default priors (1 K of common offset takes part of it: a model
    error would move both temperatures too)."""
    wins, truth = synthetic_day(150, seed=1)
    est = make(**CALIBRATED)
    errs = [est.tick(w).moisture_in - t for w, t in zip(wins, truth[:, 0], strict=True)]
    assert np.sqrt(np.mean(np.square(errs[10:]))) < 0.01
    est = make(moisture_in_walk=0.01)
    errs = [est.tick(w).moisture_in - t for w, t in zip(wins, truth[:, 0], strict=True)]
    assert np.sqrt(np.mean(np.square(errs[10:]))) < 0.02


def test_a_step_of_the_inlet_moisture_is_taken_at_once_and_settled_by_the_next_lab():
    """The temperatures cannot tell an inlet-moisture step from a heat-input step (both move
    them together); the inlet moisture is the one that steps, so its prior is widened and it
    takes the step at once; the next lab result, which sees the inlet moisture through the
    outlet moisture, confirms it."""
    wins, truth = synthetic_day(60, seed=2, x_in=lambda k: 1.0 if k < 30 else 1.12)
    labs = {36: [lab(32, truth[32, 1], "L")]}
    bodies = run(make(**NO_GAIN), wins, labs)  # the model's response is the plant's here
    assert any("along the inlet moisture" in n for n in bodies[30]["notes"])
    assert 1.08 < bodies[30]["moisture_in"] < 1.12 + 0.01     # at once
    assert abs(bodies[36]["moisture_in"] - 1.12) < 0.02        # the lab settles it
    assert abs(bodies[-1]["moisture_out"] - truth[-1, 1]) < 0.006
    assert all(b["status"] == "ok" for b in bodies[1:])
    # without covariance matching the walk takes many ticks, even with the lab
    slow = run(make(moisture_in_adapt=1e9, offset_adapt=1e9), wins, labs)
    assert abs(slow[30]["moisture_in"] - 1.12) > 0.06


# ---------------------------------------------------------------------------------- lab results
def run(est: UkfEstimator, wins, deliveries: dict[int, list[LabResult]]) -> list[dict]:
    """Tick ``wins``; deliver ``deliveries[k]`` just before tick ``k``."""
    out = []
    for k, w in enumerate(wins):
        for r in deliveries.get(k, []):
            est.add_lab(r)
        out.append(est.tick(w).to_body())
    return out


class HalfResponseDryer(LinearDryer):
    """A plant whose outlet moisture follows the inlet moisture half as much as the model's
    (its fibre leaves nearer equilibrium): the inlet gain's case."""

    def outputs(self, U: np.ndarray) -> np.ndarray:
        y = super().outputs(U)
        y[..., 2] -= 0.5 * A[2, 0] * (np.asarray(U, float)[..., 7] - U0.moisture_in)
        return y


def test_inlet_gain_learns_a_weaker_response_from_the_labs():
    """The inlet moisture swings +-0.08 kg/kg; the plant's outlet moisture follows it half as
    much as the model's. With the inlet gain the labs teach the filter the weaker response
    (gain near -0.5) and the estimate between labs halves its error; held at zero, the bias
    jumps back at every lab and the model's full swing shows in between."""
    plant = HalfResponseDryer()
    wins, truth = synthetic_day(150, seed=21, plant=plant,
                                x_in=lambda k: 1.0 + 0.08 * math.sin(k / 12.0))
    labs = {k: [lab(k - 3, truth[k - 3, 1], f"L{k}")] for k in range(8, 150, 6)}
    learned = run(make(**CALIBRATED, inlet_gain_std=1.0), wins, labs)
    held = run(make(**CALIBRATED), wins, labs)  # no history: the gain is held at zero

    def err(bodies: list[dict]) -> float:
        e = [b["moisture_out"] - t for b, t in zip(bodies[75:], truth[75:, 1], strict=True)]
        return float(np.sqrt(np.mean(np.square(e))))

    assert learned[-1]["inlet_gain"] == pytest.approx(-0.5, abs=0.15)
    assert err(learned) < 0.5 * err(held)
    assert abs(held[-1]["inlet_gain"]) < 1e-6


def test_late_lab_gives_the_same_estimate_as_an_on_time_one():
    wins, truth = synthetic_day(40, seed=4)
    samples = [lab(10, truth[10, 1] + 0.005, "A"), lab(20, truth[20, 1] - 0.006, "B")]
    on_time = run(make(), wins, {10: [samples[0]], 20: [samples[1]]})
    late = run(make(), wins, {15: [samples[0]], 29: [samples[1]]})   # 50 and 90 min late
    none = run(make(), wins, {})
    assert late[-1] == on_time[-1]                           # bit for bit
    assert late[15]["lab_updated"] and not late[14]["lab_updated"]
    assert late[15]["moisture_out"] != none[15]["moisture_out"]     # the lab did change it
    assert late[12]["moisture_out"] == none[12]["moisture_out"]     # published before arrival


def test_out_of_order_labs_give_the_same_estimate_as_in_order():
    wins, truth = synthetic_day(40, seed=5)
    a, b = lab(8, truth[8, 1] + 0.004, "A"), lab(14, truth[14, 1] - 0.005, "B")
    in_order = run(make(), wins, {18: [a], 19: [b]})
    swapped = run(make(), wins, {18: [b], 19: [a]})
    together = run(make(), wins, {19: [b, a]})
    assert in_order[-1] == swapped[-1] == together[-1]


def test_duplicate_sample_id_is_ignored():
    wins, truth = synthetic_day(30, seed=6)
    est = make()
    run(est, wins[:12], {})
    first = lab(8, truth[8, 1] + 0.004, "A")
    assert est.add_lab(first) is None
    reason = est.add_lab(dataclasses.replace(first, moisture_out=first.moisture_out + 0.02))
    assert reason is not None and "duplicate" in reason and "'A'" in reason
    assert est.add_lab(first) is not None
    once = make()
    run(once, wins[:12], {})
    once.add_lab(first)
    assert run(est, wins[12:], {})[-1] == run(once, wins[12:], {})[-1]


@pytest.mark.parametrize("value, words", [
    (float("nan"), "not finite"),
    (-0.02, "outside the plausible range"),
    (2.5, "outside the plausible range"),
])
def test_corrupted_lab_values_cannot_reach_the_estimator(value, words):
    """The lab-result contract (softsensor.messages) refuses them when a result is made: the
    estimator never holds one to check."""
    with pytest.raises(IngestError, match=words) as info:
        lab(5, value, "X")
    assert "'X'" in str(info.value)


def test_a_possible_but_implausible_lab_value_meets_the_gate_and_changes_nothing():
    """0.3 kg/kg is within the contract's range (what a lab can report) and the plant lab's
    envelope, but no estimate's: the statistical gate refuses it, with the reason, and the
    estimate is as without it."""
    wins, truth = synthetic_day(20, seed=7)
    est, ref = make(), make()
    run(est, wins[:10], {})
    run(ref, wins[:10], {})
    reason = est.add_lab(lab(5, 0.3, "X"))
    assert reason is not None and "rejected as an outlier" in reason and "'X'" in reason
    assert run(est, wins[10:], {}) == run(ref, wins[10:], {})


def test_a_lab_sampled_after_it_was_logged_cannot_be_made():
    with pytest.raises(IngestError, match="after the result arrived"):
        LabResult(T0_NS + 5 * W_NS, 0.1, "T", T0_NS + 4 * W_NS)


def test_a_lab_handed_over_before_its_window_is_skipped_not_held():
    """Results wait for their window in one queue, the service's (LabResult.due_ns): one
    handed over early is not held for later ticks (it would be a second queue)."""
    wins, truth = synthetic_day(12, seed=9)
    est = make()
    early = {3: [lab(8, truth[8, 1], "EARLY")]}  # sampled in window 8, handed over at 3
    assert run(est, wins, early) == run(make(), wins, {})
    assert "EARLY" in est._labs.seen  # accepted once (a duplicate later is still one)


def test_lab_older_than_the_history_is_skipped_with_a_reason():
    wins, truth = synthetic_day(20, seed=8)
    est, ref = make(history_hours=1.0, consistency_ticks=6), \
        make(history_hours=1.0, consistency_ticks=6)
    run(est, wins[:15], {})
    run(ref, wins[:15], {})
    reason = est.add_lab(lab(2, truth[2, 1] + 0.01, "OLD"))
    assert reason is not None and "older than the kept history" in reason
    assert run(est, wins[15:], {}) == run(ref, wins[15:], {})


def test_a_lone_outlier_is_refused_and_a_second_the_temperatures_allow_taken():
    """0.05 kg/kg above the estimate twice: within what the temperatures allow (the model's
    outlet-moisture bias spread, 0.01 kg/kg), so the second is taken and the bias follows."""
    wins, truth = synthetic_day(40, seed=9)
    est = make()
    run(est, wins[:20], {4: [lab(2, truth[2, 1], "G1")], 9: [lab(7, truth[7, 1], "G2")]})
    r1 = est.add_lab(lab(12, truth[12, 1] + 0.05, "O1"))
    assert r1 is not None and "outlier" in r1
    assert est.add_lab(lab(16, truth[16, 1] + 0.05, "O2")) is None
    body = est.tick(wins[20]).to_body()
    assert body["moisture_out_bias"] > 0.03                  # covariance matching took it
    assert any("bias" in n for n in body["notes"])


def _issue31_start(seed: int = 9):
    """A linear day with two good labs and 20 ticks, its estimator and a reference that
    sees the same (issue 31 item 5)."""
    wins, truth = synthetic_day(40, seed=seed)
    good = {4: [lab(2, truth[2, 1], "G1")], 9: [lab(7, truth[7, 1], "G2")]}
    est, ref = make(), make()
    run(est, wins[:20], good)
    run(ref, wins[:20], good)
    return wins, truth, est, ref


def test_a_copied_typo_outside_the_lab_envelope_is_refused_however_often():
    """Issue 31 item 5: 0.999 kg/kg (inside the 0..2 contract) sent twice: the first was
    refused as an outlier, the second taken (the previous result was on the same side) and
    the estimate went to 0.6 kg/kg; with 50 copies every second one was let in. Outside the
    plant lab's envelope each is refused and counted, and the estimate is as without them;
    the corrected result may follow under the same sample id."""
    wins, truth, est, ref = _issue31_start()
    for i in range(50):
        reason = est.add_lab(lab(10 + i % 9, 0.999, f"T{i % 2}"))
        assert reason is not None and "outside the plant lab's envelope 0.02..0.4" in reason
    assert run(est, wins[20:26], {}) == run(ref, wins[20:26], {})
    fixed = lab(12, truth[12, 1], "T0")
    assert est.add_lab(fixed) is None and ref.add_lab(fixed) is None
    assert run(est, wins[26:], {}) == run(ref, wins[26:], {})
    for bad in ({"lab_envelope_min": 0.3, "lab_envelope_max": 0.2},
                {"lab_envelope_max": 2.5}):
        with pytest.raises(ConfigError, match="lab_envelope"):
            estimator_settings(dataclasses.replace(CFG, extra={"estimator": bad}))


def test_a_copied_typo_inside_the_envelope_is_refused_and_said():
    """0.30 kg/kg where the temperatures say 0.10: the model's outlet moisture cannot be that
    far off, so no copy is taken; from the second in a row the health says the labs and the
    sensor disagree (degraded), and the estimate itself is as without them."""
    wins, truth, est, ref = _issue31_start()
    for i in range(6):
        reason = est.add_lab(lab(10 + i, 0.30, f"C{i}"))
        assert reason is not None and "rejected as an outlier" in reason
        if i:
            assert "the temperatures do not allow it" in reason
    body, plain = est.tick(wins[20]).to_body(), ref.tick(wins[20]).to_body()
    assert body["moisture_out"] == plain["moisture_out"]
    assert body["status"] == "degraded" and plain["status"] == "ok"
    assert "6 lab results in a row refused above the estimate" in body["detail"]
    assert est.add_lab(lab(17, truth[17, 1], "OK")) is None  # a good one ends the streak
    assert est.tick(wins[21]).to_body()["status"] == "ok"


def test_a_taken_outlier_contradicted_by_later_labs_is_withdrawn_within_a_tick():
    """Two copies of 0.05 kg/kg too high, within what the temperatures allow: the second is
    taken and pulls the estimate up. The next lab, in line with the plant, contradicts it:
    the taken one is withdrawn and the history filtered again, so the very next estimate is
    the one the filter gives without the typo (it took hours of a falling bias before)."""
    wins, truth, est, ref = _issue31_start()
    assert est.add_lab(lab(11, truth[11, 1] + 0.05, "D1")) is not None
    assert est.add_lab(lab(13, truth[13, 1] + 0.05, "D2")) is None  # taken
    for w in wins[20:24]:
        pulled = est.tick(w).to_body()
        ref.tick(w)
    assert pulled["moisture_out"] - truth[23, 1] > 0.02
    good = lab(22, truth[22, 1], "GOOD")
    assert est.add_lab(good) is None and ref.add_lab(good) is None
    body, plain = est.tick(wins[24]).to_body(), ref.tick(wins[24]).to_body()
    assert body["lab_updated"]
    assert body["moisture_out"] == pytest.approx(plain["moisture_out"], abs=1e-9)
    assert abs(body["moisture_out"] - truth[24, 1]) < 0.01
    assert "D2" not in {x.sample_id for r in est._history for x in r.labs}


def test_bias_state_takes_a_model_offset_from_two_labs():
    plant = LinearDryer(mo_offset=0.03)
    wins, truth = synthetic_day(60, seed=10, plant=plant)
    est = make(**CALIBRATED, **NO_GAIN, **PHYSICS_ONLY)  # an offset, not a response error
    bodies = run(est, wins, {12: [lab(8, truth[8, 1], "A")], 30: [lab(25, truth[25, 1], "B")]})
    # two labs of prior sd 0.01 take most of a 0.03 offset (without them: all of it missing)
    # and it decays with the bias's 24 h correlation time over the 6 h after the last one
    assert abs(bodies[31]["moisture_out"] - truth[31, 1]) < 0.006
    assert abs(bodies[-1]["moisture_out"] - truth[-1, 1]) < 0.012
    assert bodies[-1]["moisture_out_bias"] > 0.015
    assert abs(bodies[-1]["moisture_in"] - truth[-1, 0]) < 0.01   # inlet stays with the T


# ---------------------------------------------------------------------------------- robustness
def test_stale_window_predicts_without_update():
    wins, _ = synthetic_day(12, seed=11)
    est = make()
    before = run(est, wins[:10], {})[-1]
    stale = dataclasses.replace(wins[10], stale=True, reasons={"scans": "12 scans"})
    body = est.tick(stale).to_body()
    assert body["status"] == "stale" and "12 scans" in body["detail"]
    assert body["nis"] is None and body["nis_dof"] == 0
    s = EstimatorSettings()
    r = 600.0 / (s.moisture_in_tau_h * 3600.0)
    nominal = CFG.nominal.moisture_in
    assert body["moisture_in"] == pytest.approx(
        nominal + math.exp(-r) * (before["moisture_in"] - nominal), abs=1e-12)
    q = s.walk_per_window(s.moisture_in_walk, 600.0) ** 2 * (1 - math.exp(-2 * r)) / (2 * r)
    assert body["moisture_in_std"] == pytest.approx(
        math.sqrt(before["moisture_in_std"] ** 2 * math.exp(-2 * r) + q))
    assert est.tick(wins[11]).to_body()["status"] == "ok"


def test_missing_temperature_and_input_are_handled():
    wins, _ = synthetic_day(10, seed=12)
    est = make()
    run(est, wins[:8], {})
    w = window(8, 485.0, None, T_dryer_out=347.8, m_fiber=None)
    body = est.tick(w).to_body()
    assert body["nis_dof"] == 1                       # only T_dryer_out
    assert "holding last value of m_fiber" in body["detail"]


def test_window_out_of_order_is_refused():
    wins, _ = synthetic_day(3, seed=13)
    est = make()
    est.tick(wins[1])
    with pytest.raises(EstimationError, match="not after the last tick"):
        est.tick(wins[0])


def test_covariance_stays_symmetric_positive_definite_over_30_days():
    n = 30 * 144
    rng = np.random.default_rng(14)
    steps = np.where(rng.random(n) < 0.003, rng.choice([-0.1, 0.1], n), 0.0)
    x_in = np.clip(1.0 + np.cumsum(rng.normal(0, 0.003, n) + steps), 0.8, 1.3)
    wins, truth = synthetic_day(n, seed=14, x_in=lambda k: float(x_in[k]))
    est = make(moisture_in_walk=0.01, moisture_in_tau_h=1e5)  # a month-long random walk
    deliveries = {k: [lab(k - 5, truth[k - 5, 1] + rng.normal(0, 0.003), f"L{k}")]
                  for k in range(20, n, 18)}
    worst = np.inf
    for k, w in enumerate(wins):
        for r in deliveries.get(k, []):
            est.add_lab(r)
        body = est.tick(w).to_body()
        P = est._state.P
        assert np.array_equal(P, P.T)
        worst = min(worst, float(np.linalg.eigvalsh(P)[0]))
        assert math.isfinite(body["moisture_out"])
    assert worst > 0
    assert abs(body["moisture_in"] - x_in[-1]) < 0.02


# ---------------------------------------------------------------------------------- health
def test_one_temperature_sensor_off_is_taken_by_its_offset_and_named():
    """A 3 K offset on the cyclone thermometer: its own offset state takes it, the inlet
    moisture and the outlet moisture do not move, health says which sensor to check."""
    wins, truth = synthetic_day(80, seed=15)
    biased = [dataclasses.replace(w, means={**w.means,
                                            "T_cyclone_out": w.means["T_cyclone_out"] + 3.0})
              if k >= 20 else w for k, w in enumerate(wins)]
    labs = {k: [lab(k - 3, truth[k - 3, 1], f"L{k}")] for k in range(15, 80, 18)}
    bodies = run(make(), biased, labs)
    clean = run(make(), wins, labs)
    assert all(b["status"] == "ok" for b in bodies[1:20])
    end = bodies[-1]
    assert end["T_cyclone_out_offset"] > 2.0 and abs(end["T_dryer_out_offset"]) < 1.0
    assert abs(end["moisture_in"] - truth[-1, 0]) < 0.05
    assert abs(end["moisture_out"] - clean[-1]["moisture_out"]) < 0.006
    assert end["status"] == "degraded" and not end["fallback"]
    assert "T_cyclone_out reads +" in end["detail"] and "check its sensor" in end["detail"]


def test_a_model_error_shared_by_both_temperatures_goes_to_the_common_offset():
    """The plant runs 1.5 K warmer than the model on both channels (energy balance off) while
    its inlet moisture wanders +-0.05 kg/kg: the heat input's offset takes the 1.5 K and the
    inlet moisture and outlet moisture follow the truth."""
    plant = LinearDryer(T_offset=1.5)
    wins, truth = synthetic_day(120, seed=18, plant=plant)
    labs = {k: [lab(k - 3, truth[k - 3, 1] + 0.002 * (-1) ** k, f"L{k}")]
            for k in range(15, 120, 18)}
    end = run(make(moisture_in_walk=0.01), wins, labs)[-1]
    assert end["T_offset"] > 0.7 and end["T_air_in_offset"] > 2.0
    assert abs(end["moisture_in"] - truth[-1, 0]) < 0.05
    assert abs(end["moisture_out"] - truth[-1, 1]) < 0.006
    assert end["status"] == "ok" and not end["fallback"]


def test_a_model_that_has_lost_the_plant_publishes_the_last_lab_flagged():
    """Outlet temperatures 20 K off the model's: no inlet moisture in its range explains
    them, the estimate sits at the bound, and the guard publishes the last lab result with a
    wide band, health degraded and why."""
    plant = LinearDryer(T_offset=20.0)
    wins, truth = synthetic_day(80, seed=19, plant=plant)
    labs = {k: [lab(k - 2, truth[k - 2, 1], f"L{k}")] for k in range(10, 80, 12)}
    bodies = run(make(**CALIBRATED), wins, labs)
    end = bodies[-1]
    assert end["fallback"] and end["status"] == "degraded"
    assert "model lost the plant" in end["detail"] and "bound of its range" in end["detail"]
    last = [r for k, v in labs.items() if k <= 79 for r in v][-1]
    assert end["moisture_out"] == pytest.approx(last.moisture_out)
    assert end["moisture_out_std"] > EstimatorSettings().lab_std
    assert abs(end["moisture_out"] - truth[-1, 1]) < 0.01


def test_a_bias_beyond_its_prior_degrades_the_health_and_keeps_tracking_the_labs():
    """Outlet moisture 0.06 kg/kg off the model (six times the bias the estimator expects):
    not a lost model (the temperatures are right), so the filter's estimate stays published,
    following the labs, with health degraded and the bias named."""
    plant = LinearDryer(mo_offset=0.06)
    wins, truth = synthetic_day(80, seed=19, plant=plant)
    labs = {k: [lab(k - 2, truth[k - 2, 1], f"L{k}")] for k in range(10, 80, 12)}
    end = run(make(**CALIBRATED, **NO_GAIN), wins, labs)[-1]  # an offset, not a response
    assert not end["fallback"] and end["status"] == "degraded"
    assert "moisture_out_bias" in end["detail"]
    assert abs(end["moisture_out"] - truth[-1, 1]) < 0.01


def test_the_fallback_at_a_lab_tick_is_that_lab_whether_it_came_on_time_or_late():
    """A lost model publishes the last lab result; at the tick whose window holds a result,
    that is the result itself, and the same whether it was delivered on time (applied at the
    tick) or late (the tick re-filtered)."""
    plant = LinearDryer(T_offset=20.0)
    wins, truth = synthetic_day(60, seed=23, plant=plant)
    samples = {k: lab(k, truth[k, 1], f"L{k}") for k in range(8, 50, 10)}
    on_time = run(make(**CALIBRATED), wins, {k: [r] for k, r in samples.items()})
    late = run(make(**CALIBRATED), wins, {k + 2: [r] for k, r in samples.items()})
    anchored = [k for k in samples if on_time[k]["fallback"]]
    assert len(anchored) >= 3
    for k in anchored:
        assert on_time[k]["moisture_out"] == pytest.approx(samples[k].moisture_out)
        assert on_time[k]["detail"].count(f"last lab result L{k} ") == 1
    assert late[-1] == on_time[-1]


def test_the_inlet_moisture_and_its_sigma_points_stay_in_their_range():
    """A plant whose temperatures ask for an inlet moisture above the range: the estimate
    approaches the bound and never passes it, and the guard says so."""
    s = EstimatorSettings()
    tr = InletTransform(s.moisture_in_min, s.moisture_in_max, s.inlet_margin)
    sv = np.linspace(-1.0, 4.0, 2001)
    X = tr.forward(sv)
    assert np.all(X > s.moisture_in_min) and np.all(X < s.moisture_in_max)
    assert np.all(np.diff(X) > 0)
    np.testing.assert_allclose(tr.inverse(X[(X > 0.5) & (X < 2.2)]),
                               sv[(X > 0.5) & (X < 2.2)], atol=1e-9)
    np.testing.assert_array_equal(tr.forward(1.0), 1.0)  # identity inside
    wins, _ = synthetic_day(60, seed=20, x_in=lambda k: 3.5)
    bodies = run(make(), wins, {})
    assert all(s.moisture_in_min <= b["moisture_in"] <= s.moisture_in_max for b in bodies)
    assert bodies[-1]["moisture_in"] > 2.0
    assert bodies[-1]["status"] == "degraded" and "model lost the plant" in bodies[-1]["detail"]


def test_adaptive_noise_widens_the_band_when_the_plant_moves():
    """One thermometer's error wanders much faster than the calibration said: its
    innovations grow, its offset's process noise is inflated, and the innovations normalised
    by what the filter expects come back towards their degrees of freedom."""
    wins, _ = synthetic_day(100, seed=21)
    rng = np.random.default_rng(21)
    wander = np.cumsum(rng.normal(0.0, 0.4, len(wins)))
    moved = [dataclasses.replace(w, means={**w.means,
                                           "T_dryer_out": w.means["T_dryer_out"] + wander[k]})
             for k, w in enumerate(wins)]
    jumps_off = {"offset_adapt": 1e9, "moisture_in_adapt": 1e9}  # the wander, not its steps
    still = make(**jumps_off)
    run(still, wins, {})
    adaptive = make(**jumps_off)
    nis_a = [b["nis"] for b in run(adaptive, moved, {})[50:]]
    fixed = make(adapt_limit=1.0, **jumps_off)
    nis_f = [b["nis"] for b in run(fixed, moved, {})[50:]]
    infl = np.array(adaptive._state.adapt["factor"])
    assert infl[0] > 4.0
    assert np.array(still._state.adapt["factor"])[:2].max() < 2.0
    # the band follows: the innovations, normalised by what the filter expects, come closer
    # to their degrees of freedom (2) than without the adaptation
    assert abs(np.mean(nis_a) - 2.0) < 0.8 * abs(np.mean(nis_f) - 2.0)


def test_chi_square_test_false_alarm_rate_matches_alpha():
    rng = np.random.default_rng(16)
    alarms = 0
    for _ in range(4000):
        window_ = [Innovation(float(rng.chisquare(2)), 2, {"T": 0.0}) for _ in range(12)]
        alarms += chi_square_test(window_, 0.01).status == "degraded"
    assert 0.006 < alarms / 4000 < 0.015
    assert chi_square_test([], 0.01).status == "ok"


# ---------------------------------------------------------------------------------- restart
def test_restart_from_checkpoint_continues_the_same_estimate():
    wins, truth = synthetic_day(40, seed=17)
    deliveries = {12: [lab(9, truth[9, 1] + 0.004, "A")],
                  20: [lab(20, truth[20, 1], "P")],        # for the tick after the checkpoint
                  25: [lab(17, truth[17, 1] - 0.004, "B")]}
    straight = run(make(), wins, deliveries)
    first = make()
    run(first, wins[:20], {k: v for k, v in deliveries.items() if k < 20})
    first.add_lab(deliveries[20][0])                    # held across the restart
    snap = json.loads(json.dumps(first.checkpoint(), allow_nan=False))
    second = make()
    second.restore(snap)
    assert second.add_lab(deliveries[12][0]) is not None     # duplicates remembered
    rest = run(second, wins[20:], {k - 20: v for k, v in deliveries.items() if k > 20})
    assert rest == straight[20:]


def test_a_checkpoint_of_another_calibration_keeps_the_inlet_and_reseeds_the_rest(caplog):
    wins, truth = synthetic_day(40, seed=17, x_in=lambda k: 1.12)
    deliveries = {12: [lab(9, truth[9, 1] + 0.01, "A")], 18: [lab(16, truth[16, 1] + 0.01, "B")]}
    first = make(**CALIBRATED)
    run(first, wins[:20], deliveries)
    snap = json.loads(json.dumps(first.checkpoint(), allow_nan=False))
    old = FilterState.from_json(snap["state"])
    assert abs(first.inlet.forward(old.x[X_IN]) - 1.12) < 0.03   # it had found the inlet
    assert abs(old.x[X_BIAS]) > 1e-3                               # and learned a bias

    same = make(**CALIBRATED)
    same.restore(snap)                                             # the same calibration
    assert np.array_equal(same._state.x, old.x)

    recalibrated = UkfEstimator(CFG.with_parameters({"mult_h": 1.1}),
                                dataclasses.replace(EstimatorSettings(), **CALIBRATED),
                                model=LinearDryer())
    fresh = recalibrated._state
    with caplog.at_level(logging.WARNING, logger="softsensor.estimation.ukf"):
        recalibrated.restore(snap)
    assert "checkpoint made under another calibration (changed: parameters)" in caplog.text
    new = recalibrated._state
    assert new.x[X_IN] == old.x[X_IN] and new.P[X_IN, X_IN] == old.P[X_IN, X_IN]
    assert np.array_equal(new.x[1:], fresh.x[1:])                  # the old bias is gone
    assert np.array_equal(new.P[1:, 1:], fresh.P[1:, 1:]) and new.wall is None
    assert recalibrated._dirty == 0                                # kept hours run again
    rest = run(recalibrated, wins[20:], {})
    assert all(abs(r["moisture_in"] - 1.12) < 0.05 for r in rest[:3])


def test_a_moving_inlet_air_temperature_widens_the_temperature_rows():
    """The temperature rows' variance grows by (transient_fraction * heat_gain * spread)^2
    with the spread of T_air_in's bin means inside the window (ukf_step.transient_variance);
    the lab rows keep theirs, and a calm window has none."""
    est = make()
    f = est.filter
    base = window(0, 485.0, (float(Y0[0]), float(Y0[1])))
    spread = [475.0 + 2.0 * i for i in range(10)]  # 60 s bins from 475 to 493 K
    moving = dataclasses.replace(base, bin_s=60.0, bins={"T_air_in": spread})
    assert transient_variance(f, base) == 0.0
    extra = (f.settings.transient_fraction * f.heat_gain * 18.0) ** 2
    assert transient_variance(f, moving) == pytest.approx(extra)
    labs = (lab(0, 0.1, "L"),)
    zero = np.zeros(3)
    calm = measurements(f, TickData(base, est._hold.inputs(base)[0], labs), zero, zero)
    swung = measurements(f, TickData(moving, est._hold.inputs(moving)[0], labs), zero, zero)
    assert calm.rows == swung.rows == [0, 1, 2]
    np.testing.assert_allclose(np.diag(swung.R) - np.diag(calm.R), [extra, extra, 0.0])


def test_restore_refuses_a_foreign_checkpoint():
    est = make()
    with pytest.raises(EstimationError, match="kind 'openloop'"):
        est.restore({"kind": "openloop", "version": 2})
    snap = make().checkpoint()
    snap["state"]["x"] = [1.0, 0.0, 0.0]
    with pytest.raises(EstimationError, match="shapes"):
        est.restore(snap)
    snap = make().checkpoint()
    snap["hold"] = snap["hold"][:-1]  # a checkpoint of a model with one input fewer
    with pytest.raises(EstimationError, match=r"hold\(7,\)"):
        est.restore(snap)


# ---------------------------------------------------------------------------------- settings
def test_settings_default_without_estimator_table_and_validated_with_one():
    assert estimator_settings(CFG) == EstimatorSettings()
    good = dataclasses.replace(CFG, extra={"estimator": {"moisture_in_walk": 0.02}})
    assert estimator_settings(good).moisture_in_walk == 0.02
    for table, words in [({"moisture_in_wlak": 0.1}, "estimator.moisture_in_wlak is not a known"),
                         ({"lab_std": -1.0}, "estimator.lab_std must be > 0"),
                         ({"kind": "kalman"}, "estimator.kind must be one of ukf, openloop"),
                         ({"moisture_out_min": 0.5, "moisture_out_max": 0.2},
                          "estimator.moisture_out_max must be >"),
                         ({"lab_max": 0.6}, "estimator.lab_max is not a key any more: the "
                                            "plant lab's envelope is estimator.lab_envelope")]:
        bad = dataclasses.replace(CFG, extra={"estimator": table})
        with pytest.raises(ConfigError, match=words.replace(".", r"\.")):
            estimator_settings(bad)
    with pytest.raises(ConfigError, match="consistency_ticks"):
        UkfEstimator(dataclasses.replace(CFG, extra={"estimator": {"history_hours": 1.0}}),
                     model=LinearDryer())


def test_state_layout_keeps_the_model_states_first():
    """Only the inlet moisture and the heat input move the model, and with them first the
    sigma points hold five distinct pairs of them (the module docstring's step 2)."""
    assert (X_IN, X_HEAT) == (0, 1) and X_BIAS == len(STATE_NAMES) - 2
    est = make()
    n = len(STATE_NAMES)
    sig = est.filter.points.sigma_points(np.zeros(n), np.diag([0.01, 1.0, 0.25, 0.25, 1e-4,
                                                               0.5]) + 0.001)
    assert len(np.unique(sig[:, [X_IN, X_HEAT]], axis=0)) == 5


def test_the_learned_discrepancy_is_taken_off_the_measurements(tmp_path):
    """A history that learned the model reads ``T_dryer_out`` 2 K low everywhere: the plant
    reading 2 K above the model is then normal. The learned discrepancy comes off the
    measurement, so the channel's offset state stays near zero and the model temperature
    published is the measured one; taken as news, the offset state would carry the 2 K."""
    from softsensor.calibration.params_file import params_document, write_params
    from softsensor.estimation.model_error import FEATURES, no_model_error
    from softsensor.plantconfig import load_parameters

    neutral = no_model_error(FEATURES, np.zeros(len(FEATURES)), np.ones(len(FEATURES)))
    me = dataclasses.replace(neutral, T_dryer_out=dataclasses.replace(
        neutral.T_dryer_out, intercept=2.0, day_sd=0.3, noise=0.05))
    values = {n: CFG.parameters[n].value for n in CFG.parameters}
    cfg = load_parameters(write_params(tmp_path / "p.toml", params_document(
        CFG, values, {}, model_error=me.to_table())), CFG)
    wins, _ = synthetic_day(60, seed=15)
    shifted = [dataclasses.replace(w, means={**w.means,
                                             "T_dryer_out": w.means["T_dryer_out"] + 2.0})
               for w in wins]
    est = UkfEstimator(cfg, dataclasses.replace(EstimatorSettings(), **CALIBRATED),
                       model=LinearDryer())
    bodies = run(est, shifted, {})
    # measured: -0.02 K with the discrepancy taken off, +1.95 K when it is not (the
    # mutation in tests/support/mutation_check.py); the published model temperature and the inlet
    # moisture come out alike either way (the offset state absorbs the 2 K), so they are not
    # what this checks
    assert abs(bodies[-1]["T_dryer_out_offset"]) < 0.2, bodies[-1]["T_dryer_out_offset"]


def test_the_first_lab_of_a_fresh_estimator_meets_the_gate_of_the_calibration():
    """Issue 49 (fifth probe): a fresh daemon's first lab at the envelope's low edge (0.02
    kg/kg, the estimate 0.11) was taken, the estimate's spread being the fresh filter's wide
    one, and moved the published moisture for six windows; 42 results later the same value
    was refused at 17.8 sigma. The gate now judges the first results with the spread the
    calibration's history gives the model's outlet moisture (the bias state's prior) too."""
    wins, truth = synthetic_day(12, seed=11)
    est, ref = make(), make()
    run(est, wins[:3], {})
    run(ref, wins[:3], {})
    first = est.tick(wins[3]).to_body()
    ref.tick(wins[3])
    assert first["moisture_out_std"] > 0.015  # a fresh filter: wide
    value = 0.02  # the envelope's low edge, 0.07 below the estimate
    reason = est.add_lab(lab(3, value, "LOW"))
    assert reason is not None and "rejected as an outlier" in reason, first
    assert run(est, wins[4:], {}) == run(ref, wins[4:], {})
