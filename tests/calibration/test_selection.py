"""Window selection (``softsensor/calibration/selection.py``): the window with the most natural
variability, the whole record when it is short, and the refusals. Pure numpy/pandas, no model
runs."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_days import labs_every, make_day

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.selection import select_windows
from softsensor.errors import IngestError


def test_selection_picks_the_window_with_the_production_change(config):
    day = make_day(30.0, config, step_at_h=20.0, labs=labs_every(30.0, 2.0))
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
    seg = segment_from_day(make_day(5.0, config, labs=labs_every(5.0, 2.0)), config)
    (choice,) = select_windows(seg, hours=48.0)
    assert choice.whole_record and choice.segment is seg and "whole record" in choice.reason
    with pytest.raises(IngestError, match="too short to calibrate"):
        select_windows(segment_from_day(make_day(1.5, config), config), hours=48.0)
    with pytest.raises(IngestError, match="lab sample"):
        select_windows(segment_from_day(make_day(5.0, config), config), hours=48.0)
    with pytest.raises(IngestError, match="no 4 h window holds 3 lab samples"):
        select_windows(segment_from_day(make_day(12.0, config, labs=labs_every(12.0, 5.0)),
                                        config), hours=4.0)
