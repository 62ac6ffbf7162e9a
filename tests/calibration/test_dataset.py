"""Calibration data: resampling to 600 s windows, lab alignment, window selection, eq. 4,
PARAMS.toml. Pure numpy/pandas, no model runs."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from softsensor.calibration.cost import ModelRun, evaluate_fit, residuals
from softsensor.calibration.dataset import Segment, segment_from_day
from softsensor.calibration.params_file import dumps, params_document, read_fit, write_params
from softsensor.calibration.selection import select_windows
from softsensor.configfile import read_toml
from softsensor.errors import ConfigError, IngestError
from softsensor.plantconfig import PARAMETER_NAMES, load_parameters
from softsensor.recording.mcap_day import RecordedDay
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS

NS = 1_000_000_000
T0 = 1_767_571_200 * NS  # a multiple of 600 s


def make_day(hours: float, config, *, start_ns: int = T0, labs=None, step_at_h=None,
             scan_s: float = 10.0, path: str = "synthetic.mcap") -> RecordedDay:
    """Scans every ``scan_s`` s at the nominal point; ``m_fiber`` steps up at ``step_at_h``;
    T_dryer_out = 340 + hour of day (so window means are known exactly)."""
    n = int(round(hours * 3600 / scan_s)) + 1
    t = start_ns + (np.arange(n) * scan_s * NS).astype(np.int64)
    nom = config.nominal
    hrs = (t - start_ns) / 3.6e12
    data = {name: np.full(n, float(getattr(nom, name, 50.0))) for name in SCAN_SIGNALS}
    data["m_fiber"] = np.where(hrs >= (step_at_h if step_at_h is not None else 1e9), 6.8, 5.0)
    data["T_dryer_out"] = 340.0 + hrs
    data["T_cyclone_out"] = 338.0 + hrs
    scans = pd.DataFrame(data, index=pd.Index(t, name="log_time_ns"))
    labs = labs if labs is not None else []
    lab_df = pd.DataFrame({
        "log_time_ns": np.array([r[0] for r in labs], dtype=np.int64),
        "sample_time_ns": np.array([r[1] for r in labs], dtype=np.int64),
        "moisture_out": np.array([r[2] for r in labs], dtype=float),
        "sample_id": pd.Series([f"L{i}" for i in range(len(labs))], dtype=str)})
    return RecordedDay(path=Path(path), scans=scans, labs=lab_df, truth=None)


def test_windows_are_half_open_means_of_scans(config):
    day = make_day(2.0, config)
    seg = segment_from_day(day, config)
    assert seg.start_ns == T0 and seg.n_windows == 12 and seg.window == 600.0
    # window k holds scans at (T0 + 600 k, T0 + 600 (k+1)]: times 10..600 s -> hours mean
    k = np.arange(12)
    expected = 340.0 + (600 * k + np.arange(10, 601, 10).mean()) / 3600.0
    np.testing.assert_allclose(seg.Y[:, 0], expected, rtol=0, atol=1e-9)
    assert np.isnan(seg.Y[:, 2]).all()  # moisture comes from the lab
    assert np.all(seg.U[:, INPUT_NAMES.index("moisture_in")] == config.nominal.moisture_in)
    np.testing.assert_array_equal(seg.window_ends_ns(), T0 + 600 * NS * (k + 1))


def test_first_window_starts_on_the_grid_after_the_first_scan(config):
    day = make_day(2.0, config, start_ns=T0 + 123 * NS)
    seg = segment_from_day(day, config)
    assert seg.start_ns == T0 + 600 * NS
    assert seg.n_windows == 11  # 2 h minus the partial first and last windows


def test_missing_input_windows_hold_the_last_value_and_outputs_drop_out(config):
    day = make_day(2.0, config, step_at_h=0.25)
    t = day.scans.index.to_numpy()
    gap = (t > T0 + 3 * 600 * NS) & (t <= T0 + 4 * 600 * NS)  # window 3 entirely
    scans = day.scans.copy()
    scans.loc[gap, "m_fiber"] = np.nan
    scans.loc[gap, "T_cyclone_out"] = np.nan
    few = (t > T0 + 5 * 600 * NS) & (t <= T0 + 6 * 600 * NS - 200 * NS)  # 40 of 60 missing
    scans.loc[few, "T_dryer_out"] = np.nan
    day = RecordedDay(path=day.path, scans=scans, labs=day.labs, truth=None)
    seg = segment_from_day(day, config)
    j = INPUT_NAMES.index("m_fiber")
    assert seg.U[3, j] == seg.U[2, j] == pytest.approx(6.8)  # held
    # a window without a model input is stale, as the estimator sees it: its temperatures
    # are not compared (the model ran on held inputs there)
    assert np.isnan(seg.Y[3]).all()
    assert np.isnan(seg.Y[5, 0]) and np.isfinite(seg.Y[5, 1])  # fewer than half good


def test_labs_are_aligned_to_sample_time_not_log_time(config):
    labs = [(T0 + 5000 * NS, T0 + 1500 * NS, 0.11),   # logged late, sampled in window 2
            (T0 + 7000 * NS, T0 + 6000 * NS, 0.12),   # sampled exactly at a window end
            (T0 + 9000 * NS, T0 + 99999 * NS, 0.13)]  # sampled after the record: dropped
    day = make_day(2.0, config, labs=labs, step_at_h=1350 / 3600)
    seg = segment_from_day(day, config)
    np.testing.assert_array_equal(seg.lab_time_ns, [T0 + 1500 * NS, T0 + 6000 * NS])
    np.testing.assert_array_equal(seg.lab_window, [2, 9])
    np.testing.assert_allclose(seg.lab_offset, [300.0, 600.0])
    # inputs at the sample time: the 120 s of scans before it (production already up),
    # while window 2 averages 5.0 and 6.8
    j = INPUT_NAMES.index("m_fiber")
    assert seg.lab_U[0, j] == pytest.approx(6.8) and seg.U[2, j] < 6.8
    assert seg.lab_U[0, INPUT_NAMES.index("moisture_in")] == config.nominal.moisture_in
    # a scan gap at the sample time: the window mean is used
    scans = day.scans.copy()
    t = scans.index.to_numpy()
    scans.loc[(t > T0 + 1300 * NS) & (t <= T0 + 1500 * NS), "m_fiber"] = np.nan
    seg2 = segment_from_day(RecordedDay(day.path, scans, day.labs, None), config)
    assert seg2.lab_U[0, j] == pytest.approx(seg2.U[2, j])
    # residuals compare each lab with the model's value at its sample time
    run = ModelRun.single(np.zeros((seg.n_windows, 3)), np.array([0.1, 0.125]))
    np.testing.assert_allclose(residuals(run, seg)[2], [[0.01, -0.005]])
    assert residuals(run, seg, upto=9)[2].shape == (1, 1)  # second sample ends window 9


def test_no_window_and_missing_signal_are_one_line_errors(config):
    with pytest.raises(IngestError, match="no complete 600 s window"):
        segment_from_day(make_day(0.1, config), config)
    day = make_day(1.0, config)
    scans = day.scans.copy()
    scans["T_amb"] = np.nan
    with pytest.raises(IngestError, match="signal T_amb has no good value"):
        segment_from_day(RecordedDay(day.path, scans, day.labs, None), config)
    with pytest.raises(IngestError, match=r"synthetic\.mcap: 0 lab sample\(s\)"):
        segment_from_day(make_day(3.0, config), config).require_labs(1)


def test_eq4_cost_by_hand(config):
    seg = segment_from_day(make_day(1.0, config, labs=[(T0 + 3000 * NS, T0 + 1200 * NS, 0.1)]),
                           config)
    Y = np.empty((seg.n_windows, 3))
    Y[:, 0] = seg.Y[:, 0] + 2.0                     # 2 K off everywhere
    Y[:, 1] = seg.Y[:, 1] + np.where(np.arange(seg.n_windows) % 2, 1.0, -1.0)
    Y[:, 2] = 0.0
    run = ModelRun.single(Y, np.array([0.13]))      # 0.03 kg/kg off at the lab sample
    fit = evaluate_fit([run], [seg], config.cost.weights())[0]
    assert fit.n == {"T_dryer_out": 6, "T_cyclone_out": 6, "moisture_out": 1}
    assert fit.rmse["T_dryer_out"] == pytest.approx(2.0)
    assert fit.rmse["T_cyclone_out"] == pytest.approx(1.0)
    assert fit.rmse["moisture_out"] == pytest.approx(0.03)
    assert fit.cost == pytest.approx(0.003 * 2.0 + 0.003 * 1.0 + 5.0 * 0.03)
    # partial cost over the first window: the lab (sampled at 1200 s) is not yet in
    part = evaluate_fit([run], [seg], config.cost.weights(), upto=[1])[0]
    assert part.n["moisture_out"] == 0 and part.n["T_dryer_out"] == 1
    assert part.cost == pytest.approx(0.003 * 2.0 + 0.003 * 1.0)
    # two segments pool their samples before the root mean square
    two = evaluate_fit([run, run], [seg, seg], config.cost.weights())[0]
    assert two.n["T_dryer_out"] == 12 and two.cost == pytest.approx(fit.cost)
    # a failed model run (NaN) is an infinite cost, not a small one
    bad = Y.copy()
    bad[3, 0] = np.nan
    assert evaluate_fit([ModelRun.single(bad, np.array([0.13]))], [seg],
                        config.cost.weights())[0].cost == math.inf
    both = ModelRun(np.stack([Y, Y]), np.array([[0.13], [0.1]]))
    assert [r.shape for r in residuals(both, seg)] == [(2, 6), (2, 6), (2, 1)]
    assert [f.rmse["moisture_out"] for f in evaluate_fit([both], [seg],
                                                         config.cost.weights())] == \
        pytest.approx([0.03, 0.0])


def _labs_every(hours: float, every_h: float):
    return [(T0 + int((h + 0.5) * 3.6e12), T0 + int(h * 3.6e12), 0.1)
            for h in np.arange(0.7, hours, every_h)]


def test_selection_picks_the_window_with_the_production_change(config):
    day = make_day(30.0, config, step_at_h=20.0, labs=_labs_every(30.0, 2.0))
    seg = segment_from_day(day, config)
    (choice,) = select_windows(seg, hours=6.0)
    assert choice.k0 * 600 / 3600 <= 20.0 <= choice.k1 * 600 / 3600
    assert choice.segment.n_windows == 36 and choice.n_labs >= 3
    assert "most natural variability" in choice.reason and "m_fiber" in choice.reason
    assert choice.contributions["m_fiber"] > 1.0
    # labs of the chosen window only, times inside it
    sub = choice.segment
    assert np.all((sub.lab_time_ns > sub.start_ns) & (sub.lab_time_ns <= sub.end_ns))
    # two windows: disjoint
    a, b = select_windows(seg, hours=6.0, count=2)
    assert a.k1 <= b.k0


def test_selection_whole_record_and_errors(config):
    seg = segment_from_day(make_day(5.0, config, labs=_labs_every(5.0, 2.0)), config)
    (choice,) = select_windows(seg, hours=48.0)
    assert choice.whole_record and choice.segment is seg and "whole record" in choice.reason
    with pytest.raises(IngestError, match="too short to calibrate"):
        select_windows(segment_from_day(make_day(1.5, config), config), hours=48.0)
    with pytest.raises(IngestError, match="lab sample"):
        select_windows(segment_from_day(make_day(5.0, config), config), hours=48.0)
    with pytest.raises(IngestError, match="no 4 h window holds 3 lab samples"):
        select_windows(segment_from_day(make_day(12.0, config, labs=_labs_every(12.0, 5.0)),
                                        config), hours=4.0)


def test_segment_slice_keeps_its_labs(config):
    seg = segment_from_day(make_day(6.0, config, labs=_labs_every(6.0, 1.0)), config)
    sub = seg.slice(12, 24)
    assert isinstance(sub, Segment) and sub.n_windows == 12
    assert sub.start_ns == seg.start_ns + 12 * 600 * NS
    assert len(sub.lab_value) == 2 and "[" in sub.source


def test_params_file_round_trip(tmp_path, config):
    values = dict(zip(PARAMETER_NAMES, [0.7, 2.0, 1.4, 2.0, 1.8, 3e-4, 50.0], strict=True))
    fit = {"cost": 0.0123, "trials": 200, "seed": 7, "windows": ["a [x .. y]"],
           "rmse": {"T_dryer_out": 0.1, "T_cyclone_out": 0.2, "moisture_out": 0.004},
           "big": float("inf")}
    doc = params_document(config, values, fit, {"mult_D": "identifiable"})
    path = write_params(tmp_path / "PARAMS.toml", doc, "a comment\nline two")
    raw = read_toml(path)
    assert raw["parameters"]["mult_D"] == {"value": 0.7, "low": 0.01, "high": 5.0, "log": True,
                                           "verdict": "identifiable"}
    assert raw["fit"]["rmse"]["moisture_out"] == 0.004 and raw["fit"]["big"] == math.inf
    loaded = load_parameters(path, config)
    np.testing.assert_allclose(loaded.parameter_vector(), list(values.values()))
    assert read_fit(path)["trials"] == 200
    with pytest.raises(ConfigError, match="does not exist"):
        write_params(tmp_path / "nope" / "P.toml", doc)


def test_dumps_round_trips_through_tomllib():
    doc = {"a": {"s": 'quote " and \\ back\nnew line', "i": 3, "f": 0.1 + 0.2, "b": False,
                 "inf": -math.inf, "list": ["x", "y"], "nums": [1.5, 2.0], "gone": None,
                 "sub": {"deep": 1e-300, "none": None}},
           "empty": {}}
    text = dumps(doc, "head\n\ntail")
    assert text.startswith("# head\n#\n# tail\n")
    back = tomllib.loads(text)
    expected = {"a": {k: v for k, v in doc["a"].items() if k != "gone"}, "empty": {}}
    expected["a"]["sub"] = {"deep": 1e-300}
    assert back == expected
    assert math.isnan(tomllib.loads(dumps({"x": math.nan}))["x"])
    with pytest.raises(TypeError, match="cannot write to TOML"):
        dumps({"x": object()})
