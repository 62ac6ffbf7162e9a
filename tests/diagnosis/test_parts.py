"""Diagnosis building blocks: windows, residual statistics, extension fits, verdict rules, CLI.

The hidden-effect tests (a virtual-plant day per cause) are in
``tests/diagnosis/test_diagnose_day.py``.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.day_windows import day_windows, delagged_air
from softsensor.diagnosis.extensions import (
    AirSensorLag,
    LabTimeShift,
    SensorOffset,
    TransferDrift,
)
from softsensor.diagnosis.problem import Problem, choose_split
from softsensor.diagnosis.residuals import (
    LAB_SHIFTS_MIN,
    change_point,
    channel_stats,
    cross_correlation,
    lab_stats,
    ljung_box,
)
from softsensor.diagnosis.verdict import ALPHA, MIN_PENALISED, Score, verdict
from softsensor.errors import IngestError
from softsensor.model import DryerModel
from softsensor.model.dryer import parameter_index
from softsensor.plant.simulator import SimulatedDay, simulate_day
from softsensor.plantconfig import load_plant_config


@pytest.fixture(scope="module")
def cfg():
    return load_plant_config()


@pytest.fixture(scope="module")
def model(cfg):
    return DryerModel(cfg)


@pytest.fixture(scope="module")
def day(cfg):
    return simulate_day(cfg, 14.0, seed=5)


def _problem(cfg, model, day):
    w = day_windows(day, cfg)
    return Problem(cfg, model, w, choose_split(w, min_labs=1), model.theta0, 0.003)


# ---------------------------------------------------------------------------- windows
def test_windows_are_scan_means_and_edges_follow_t_air_in(cfg, day):
    w = day_windows(day, cfg)
    assert w.n_windows == 84  # 14 h of 600 s windows
    s = day.scans
    t0 = s.index[0]
    k = 10
    sel = s[(s.index > t0 + k * 600e9) & (s.index <= t0 + (k + 1) * 600e9)]
    assert len(sel) == 60
    np.testing.assert_allclose(w.U[k, 0], sel.T_air_in.mean())
    np.testing.assert_allclose(w.Y[k], sel[["T_dryer_out", "T_cyclone_out"]].mean())
    assert np.all(w.U[:, -1] == cfg.nominal.moisture_in)
    # an edge: the mean of the sub-window bins on either side of the boundary
    bw = 600e9 / w.segment.bins.shape[1]
    edge = t0 + k * 600e9
    before = s[(s.index > edge - bw) & (s.index <= edge)].T_air_in.mean()
    after = s[(s.index > edge) & (s.index <= edge + bw)].T_air_in.mean()
    np.testing.assert_allclose(w.air_edges[k], 0.5 * (before + after))
    assert np.all(np.diff(w.lab_time_ns) > 0) and len(w.lab_value) == len(day.labs)


def test_windows_hold_missing_inputs_and_refuse_bad_days(cfg, day):
    scans = day.scans.copy()
    scans.iloc[601:721, scans.columns.get_loc("m_air")] = np.nan  # windows 10 and 11
    w = day_windows(SimulatedDay(scans, day.labs, day.truth), cfg)
    assert w.held["m_air"] == 2 and w.U[10, 1] == w.U[9, 1] == w.U[11, 1]
    with pytest.raises(IngestError, match="signal T_cyclone_out is missing"):
        day_windows(SimulatedDay(scans.drop(columns="T_cyclone_out"), day.labs, day.truth),
                    cfg, "x.mcap")
    with pytest.raises(IngestError,
                       match="x.mcap: 1.7 h of usable windows; diagnosis needs at least 6 h"):
        day_windows(SimulatedDay(scans.iloc[:721], day.labs, day.truth), cfg, "x.mcap")


def test_lab_points_move_with_the_sample_time(cfg, model, day):
    """A lab result meets the model at its sample time: moving every sample time by one
    window gives the model's values one window later."""
    p = _problem(cfg, model, day)
    W = p.windows.window_s
    here = p.lab_points()
    later = p.lab_points(shift_ns=W * 1e9)
    assert np.all(later.window[here.window + 1 < p.windows.n_windows]
                  == here.window[here.window + 1 < p.windows.n_windows] + 1)
    # the baseline at the unmoved points is the baseline's own lab prediction
    np.testing.assert_allclose(p.baseline_labs(here), p.baseline.lab, rtol=0, atol=1e-9)


# ---------------------------------------------------------------------------- statistics
def test_ljung_box_tells_white_from_correlated():
    rng = np.random.default_rng(0)
    e = rng.standard_normal(300)
    ar = np.empty(300)
    ar[0] = e[0]
    for i in range(1, 300):
        ar[i] = 0.6 * ar[i - 1] + e[i]
    assert ljung_box(e)[1] > 0.01
    assert ljung_box(ar)[1] < 1e-10


def test_change_point_and_cross_correlation_find_what_was_put_in():
    rng = np.random.default_rng(1)
    hours = np.arange(1, 201) / 6.0
    r = 0.1 * rng.standard_normal(200)
    r[120:] += 1.0
    h, shift, t = change_point(r, hours)
    assert h == pytest.approx(hours[119]) and shift == pytest.approx(1.0, abs=0.05) and t > 20
    x = rng.standard_normal(200)
    y = np.concatenate([[0.0, 0.0], x[:-2]]) + 0.1 * rng.standard_normal(200)
    cc = cross_correlation(y, x)
    assert cc.lag == 2 and cc.corr > 0.95


def test_channel_and_lab_statistics_on_a_clean_day(cfg, model, day):
    p = _problem(cfg, model, day)
    r = p.residuals(p.baseline)
    st = channel_stats("T_dryer_out", r.T[:, 0], p.windows, p.sigma[0])
    # a clean day with the plant's own parameters: residuals are the noise of a window mean
    # (0.5 K / sqrt(60) = 0.065 K) plus a little model discretisation
    assert st.rmse < 0.15 and abs(st.t_mean) < 4 and st.structure_ratio < 1.5
    _, shifted = LabTimeShift.lab_chi2(p, LAB_SHIFTS_MIN)
    lab = lab_stats(r.lab, p.windows, p.baseline.Y[:, 2], shifted)
    assert lab.rmse < 0.008
    # the lab RMSE at every shift of the sample times, recomputed here
    curve = np.sqrt(np.mean((p.windows.lab_value - shifted) ** 2, axis=1))
    # unshifted, the moved-sample model values are the baseline's own lab predictions (one
    # batched step against the baseline's run: round-off apart, measured 1.6e-12 relative)
    assert curve[LAB_SHIFTS_MIN == 0.0][0] == pytest.approx(lab.rmse, rel=1e-9)
    # the stamps of a clean day are right: the RMSE is least at no shift (one grid step, 2
    # min, either side it is a third higher or more: measured 0.0021 against 0.0028 and
    # 0.0037 kg/kg), and lab_stats reports that shift and that RMSE
    assert lab.best_shift_min == 0.0
    assert lab.rmse_at_best_shift == pytest.approx(curve.min(), rel=1e-12)


# ---------------------------------------------------------------------------- extensions
def test_sensor_offset_recovers_an_offset_on_the_right_channel(cfg, model, day):
    scans = day.scans.copy()
    scans["T_cyclone_out"] += 2.5
    p = _problem(cfg, model, SimulatedDay(scans, day.labs, day.truth))
    f = SensorOffset().fit(p)
    assert f.channel == "T_cyclone_out"
    assert f.params["offset_K"] == pytest.approx(2.5, abs=0.05)
    # the whitened fit-part chi-square falls by far more than the calibration-error model
    # would charge for leaving the offset to its slow per-channel state
    assert p.chi2(p.baseline) - f.fit_chi2 > 10.0


def test_lab_time_shift_recovers_a_wrong_stamp(cfg, model, day):
    labs = day.labs.copy().sort_values("sample_time_ns")
    # labs report the model's own values, stamped 40 min late
    labs["sample_time_ns"] = labs.sample_time_ns + int(40 * 60e9)
    stamped = _problem(cfg, model, SimulatedDay(day.scans, labs, day.truth))
    labs["moisture_out"] = stamped.baseline_labs(stamped.lab_points(shift_ns=-40 * 60e9))
    p = _problem(cfg, model, SimulatedDay(day.scans, labs, day.truth))
    moved = np.abs(np.gradient(p.baseline.Y[:, 2])).max() > 1e-4
    assert moved
    ext = LabTimeShift()
    ext.min_chi2_drop = 0.0  # noise-free labs: any drop is real
    f = ext.fit(p)
    assert f.params["shift_min"] == pytest.approx(-40.0, abs=1.0)
    # the residual statistics see the same shift
    r = p.residuals(p.baseline)
    _, shifted = LabTimeShift.lab_chi2(p, LAB_SHIFTS_MIN)
    assert lab_stats(r.lab, p.windows, p.baseline.Y[:, 2], shifted).best_shift_min \
        == pytest.approx(-40.0, abs=2.0)


def _replace_outputs(day, p0, pred):
    """``day`` with its temperatures and labs moved from the baseline model to the prediction
    ``pred`` of an extended model (the day's own noise kept)."""
    w = p0.windows
    scans = day.scans.copy()
    k = np.clip((scans.index.to_numpy() - w.start_ns - 1) // int(600e9), 0, w.n_windows - 1)
    for c, name in enumerate(("T_dryer_out", "T_cyclone_out")):
        scans[name] = pred.Y[k, c] + (scans[name].to_numpy() - p0.baseline.Y[k, c])
    labs = day.labs.copy().sort_values("sample_time_ns")
    labs["moisture_out"] = labs.moisture_out.to_numpy() - p0.baseline.lab + pred.lab
    return SimulatedDay(scans, labs, day.truth)


def test_each_parametric_fit_recovers_its_own_model(cfg, model, day):
    """Data made by the extended model itself: each fit must recover its parameter, and on
    the clean day find (almost) nothing."""
    from softsensor.diagnosis.extensions import AmbientHeatLoss
    from softsensor.model.geometry import BETA_AMB, N_AUX

    p0 = _problem(cfg, model, day)
    drift = TransferDrift()
    # the model itself run with mult_D and mult_h falling by 30 % over the day
    t_mid = (np.arange(p0.windows.n_windows) + 0.5) / p0.windows.n_windows
    theta = np.tile(p0.theta, (p0.windows.n_windows, 1))
    for name in ("mult_D", "mult_h"):
        theta[:, parameter_index(name)] *= 1.0 - 0.3 * t_mid
    p = _problem(cfg, model, _replace_outputs(day, p0, p0.predict(theta=theta)))
    # fitted by least squares on whitened residuals: the slow calibration-error states take
    # a little of a drift (a few hundredths)
    assert drift.fit(p).params["loss_by_end"] == pytest.approx(0.3, abs=0.04)
    lag = AirSensorLag()
    w = p0.windows
    U, bins = delagged_air(w.segment, w.air_edges, 8.0 * 60.0)
    lagged = p0.predict(U, labs=p0.lab_points(U=U, bins=bins))
    p = _problem(cfg, model, _replace_outputs(day, p0, lagged))
    assert lag.fit(p).params["tau_min"] == pytest.approx(8.0, abs=0.5)
    aux = np.zeros(N_AUX)
    aux[BETA_AMB] = 0.06
    amb = AmbientHeatLoss()
    p = _problem(cfg, model, _replace_outputs(day, p0, p0.predict(aux=aux)))
    # the slow common calibration-error state takes a share of an ambient signature that
    # follows the slow ambient temperature
    assert amb.fit(p).params["beta_amb_per_K"] == pytest.approx(0.06, abs=0.015)
    clean = [lag.fit(p0).params["tau_min"], drift.fit(p0).params["loss_by_end"],
             amb.fit(p0).params["beta_amb_per_K"]]
    assert clean[0] < 2.0 and abs(clean[1]) < 0.05 and abs(clean[2]) < 0.01


# ---------------------------------------------------------------------------- cross-fitting
def test_the_reversed_split_swaps_the_parts(cfg, model, day):
    p = _problem(cfg, model, day)
    s, r = p.split, p.split.reversed()
    K = p.windows.n_windows
    assert r.fit_windows == s.held_windows and r.held_windows == s.fit_windows
    assert np.array_equal(r.lab_fit, s.lab_held) and np.array_equal(r.lab_held, s.lab_fit)
    rr = r.reversed()
    assert rr.k_fit == s.k_fit and np.array_equal(rr.lab_fit, s.lab_fit) and not rr.reverse
    assert s.sim_end(K) == s.k_fit and r.sim_end(K) == K
    q = p.reversed()
    assert q.split.reverse and np.array_equal(q.sigma, p.sigma)
    assert q.fit_part(q.baseline)[0].size == K - s.k_fit


@pytest.mark.parametrize("extension", [SensorOffset(), LabTimeShift(), TransferDrift()],
                         ids=lambda e: e.cause)
def test_cross_fitted_predictions_never_see_the_data_they_score(cfg, model, day, extension):
    """Changing the measurements of one part must not move the cross-fitted prediction of
    that part (it comes from the fold fitted on the other part), and must move the fold
    fitted on it."""
    from softsensor.diagnosis.verdict import cross_fitted

    p = _problem(cfg, model, day)
    k, t_split = p.split.k_fit, p.split.split_ns
    scans, labs = day.scans.copy(), day.labs.copy()
    early = scans.index.to_numpy() <= t_split
    scans.loc[early, "T_cyclone_out"] += 3.0
    scans.loc[early, "T_dryer_out"] -= 2.0
    early_lab = labs.sample_time_ns.to_numpy() < t_split
    labs.loc[early_lab, "moisture_out"] += 0.02
    q = _problem(cfg, model, SimulatedDay(scans, labs, day.truth))
    assert q.split.k_fit == k
    fp, bp = extension.fit_both(p)
    fq, bq = extension.fit_both(q)
    cp = cross_fitted(p, fp.prediction, bp.prediction)
    cq = cross_fitted(q, fq.prediction, bq.prediction)
    np.testing.assert_allclose(cq.Y[:k], cp.Y[:k], rtol=0, atol=1e-9)
    held_early = p.split.lab_fit
    np.testing.assert_allclose(cq.lab[held_early], cp.lab[held_early], rtol=0, atol=1e-12)
    if extension.cause != "lab_delay":  # a lab shift below its gate stays at zero on both
        # the first fold was fitted on the changed part: its prediction of the rest moves
        assert not np.allclose(fq.prediction.Y[k:], fp.prediction.Y[k:], rtol=0, atol=1e-6)


def test_the_reported_gain_is_cross_fitted_over_the_whole_day(cfg, model, day):
    """A sensor offset on the whole day: the report's numbers cover every window and lab
    result, each predicted by the fit on the other part."""
    from softsensor.diagnosis.diagnose_day import diagnose

    scans = day.scans.copy()
    scans["T_dryer_out"] += 3.0
    d = diagnose(cfg, SimulatedDay(scans, day.labs, day.truth),
                 extensions=(SensorOffset(), LabTimeShift()))
    rep = d.to_json()
    assert rep["cause"] == "sensor_bias" and rep["channel"] == "T_dryer_out"
    w = d.problem.windows
    assert rep["held_out"]["samples"]["T_dryer_out"] == int(np.isfinite(w.Y[:, 0]).sum())
    assert rep["held_out"]["samples"]["moisture_out"] == len(w.lab_value)
    r = d.problem.residuals(d.cross_fitted("sensor_bias"))
    assert rep["extended_rmse"]["T_dryer_out"] == pytest.approx(
        float(np.sqrt(np.nanmean(r.T[:, 0] ** 2))))
    # eq. 4 recomputed here from the whole day's residuals
    weights = cfg.cost.weights()

    def eq4(res):
        return sum(wc * np.sqrt(np.nanmean(x ** 2))
                   for wc, x in zip(weights, (res.T[:, 0], res.T[:, 1], res.lab), strict=True))

    base = eq4(d.problem.residuals(d.problem.baseline))
    assert rep["baseline_cost"] == pytest.approx(base)
    assert rep["extended_cost"] == pytest.approx(eq4(r))
    assert rep["gain"] == pytest.approx(1 - eq4(r) / base)
    assert rep["gain"] > 0 and rep["held_out"]["split_gain"] > 0
    assert rep["extension"]["params_other_fold"]["offset_K"] == pytest.approx(3.0, abs=0.1)


# ---------------------------------------------------------------------------- verdict rules
def _score(cause, penalised, gain=0.1, p=1e-6, worse=(), channel=None):
    h = Fit(rmse={"T_dryer_out": 1.0, "T_cyclone_out": 1.0, "moisture_out": 0.01},
            n={"T_dryer_out": 10, "T_cyclone_out": 10, "moisture_out": 3}, cost=0.1)
    return Score(cause, channel, 1, h, h, gain, h, h, gain, {"T_dryer_out": penalised + 1,
                                                 "T_cyclone_out": 0.0, "moisture_out": 0.0},
                 penalised, tuple(worse), 30.0, p)


def test_verdict_names_the_best_eligible_extension():
    v = verdict([_score("fouling_drift", 50.0), _score("inlet_moisture", 80.0, p=0.01),
                 _score("ambient_heat_loss", 20.0), _score("sensor_bias", 90.0,
                                                           worse=("T_dryer_out",))], None)
    assert v.cause == "fouling_drift"
    assert [c for c, _, _ in v.ranking][:3] == ["fouling_drift", "ambient_heat_loss", "none"]
    scores = dict((c, s) for c, s, _ in v.ranking)
    assert scores["fouling_drift"] > 0.99 and scores["inlet_moisture"] == 0.0
    assert sum(s for _, s, _ in v.ranking) == pytest.approx(1.0)


def test_verdict_none_or_unexplained_without_an_eligible_extension():
    weak = [_score("lab_delay", 3.0, p=0.5), _score("input_lag", MIN_PENALISED - 0.5)]
    assert verdict(weak, None).cause == "none"
    assert verdict(weak, "T_dryer_out residuals are 3.0 times ...").cause == "unexplained"
    assert not _score("x", 50.0, p=2 * ALPHA).eligible
    assert "not significant" in _score("x", 50.0, p=2 * ALPHA).why_not()
    assert not weak[1].eligible and "below" in weak[1].why_not()
    assert _score("x", MIN_PENALISED).eligible and _score("x", MIN_PENALISED).why_not() is None
    # the fix of a cause must lower eq. 4 on data it was not fitted on
    assert not _score("x", 50.0, gain=-0.01).eligible
    assert "gain under eq. 4" in _score("x", 50.0, gain=-0.01).why_not()
    assert "worse" in _score("x", 50.0, worse=("moisture_out",)).why_not()


# ---------------------------------------------------------------------------- CLI
def _cli(*args):
    return subprocess.run([sys.executable, "-m", "softsensor.cli", *args],
                          capture_output=True, text=True, timeout=120)


def test_cli_refuses_bad_input_with_one_line(tmp_path):
    r = _cli("diagnose", "--params", str(tmp_path / "missing.toml"), str(tmp_path / "d.mcap"),
             "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and "no such file" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    r = _cli("diagnose", str(tmp_path / "d.mcap"), "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and "--calibrate-on" in r.stderr
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    params = tmp_path / "p.toml"
    params.write_text("[parameters.mult_D]\nvalue = 1.0\n")
    r = _cli("diagnose", "--params", str(params), str(bad), "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and str(bad) in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_problem_split_keeps_labs_on_both_sides(cfg, day):
    w = day_windows(day, cfg)
    s = choose_split(w, min_labs=2)
    assert s.lab_fit.sum() >= 2 and s.lab_held.sum() >= 2
    assert 0.5 * w.n_windows <= s.k_fit <= 0.7 * w.n_windows
    assert np.all(w.lab_time_ns[s.lab_fit] < s.split_ns)
    assert s.split_ns == w.end_ns[s.k_fit - 1]


def test_unexplained_when_the_residuals_exceed_what_the_calibration_error_allows(cfg, model,
                                                                                 day):
    """A 1.5 K oscillation of 2 h period on one sensor is faster than any calibration error
    and than every extension tried here: ``unexplained``, naming the channel; the clean day
    is ``none``."""
    from softsensor.diagnosis.diagnose_day import diagnose
    from softsensor.diagnosis.verdict import structured

    scans = day.scans.copy()
    t_h = (scans.index.to_numpy() - scans.index[0]) / 3.6e12
    scans["T_cyclone_out"] += 1.5 * np.sin(2 * np.pi * t_h / 2.0)
    d = diagnose(cfg, SimulatedDay(scans, day.labs, day.truth), extensions=(LabTimeShift(),))
    assert d.cause == "unexplained"
    assert "T_cyclone_out" in d.verdict.structure and "T_dryer_out" not in d.verdict.structure
    assert structured(_problem(cfg, model, day)) is None
