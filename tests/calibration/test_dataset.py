"""Calibration data (``softsensor/calibration/dataset.py``): resampling to 600 s windows, lab
results aligned to their sample time, held inputs, the refusals, a segment's slice. Pure
numpy/pandas, no model runs."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_days import NS, T0, labs_every, make_day

from softsensor.calibration.cost import ModelRun, residuals
from softsensor.calibration.dataset import Segment, segment_from_day
from softsensor.errors import IngestError
from softsensor.recording.mcap_day import RecordedDay
from softsensor.signals import INPUT_NAMES


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


def test_segment_slice_keeps_its_labs(config):
    seg = segment_from_day(make_day(6.0, config, labs=labs_every(6.0, 1.0)), config)
    sub = seg.slice(12, 24)
    assert isinstance(sub, Segment) and sub.n_windows == 12
    assert sub.start_ns == seg.start_ns + 12 * 600 * NS
    assert len(sub.lab_value) == 2 and "[" in sub.source


