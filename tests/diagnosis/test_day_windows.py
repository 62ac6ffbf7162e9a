"""A day's 600 s windows for the diagnosis (``softsensor/diagnosis/day_windows.py``): scan
means, edges of the inlet air temperature, held inputs and the days refused."""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.diagnosis.day_windows import day_windows
from softsensor.errors import IngestError
from softsensor.plant.simulator import SimulatedDay


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
