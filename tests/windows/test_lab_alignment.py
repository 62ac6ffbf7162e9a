"""Lab alignment (``softsensor/windows/lab_alignment.py``): a lab sample finds the window that
ends at or after it, and the inputs of the minutes before it (``tests/support/mutation_check.py``
moves the boundary and shortens the span)."""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.windows.lab_alignment import (
    MIN_OFFSET_S,
    sample_inputs_from_bins,
    sample_offset,
    window_index,
)

NS = 10**9


def test_a_sample_belongs_to_the_window_that_ends_at_or_after_it():
    start, period = 1_000 * NS, 600 * NS
    t = np.array([start + 1, start + period, start + period + 1, start + 3 * period])
    np.testing.assert_array_equal(window_index(start, period, t), [0, 0, 1, 2])
    off = sample_offset(np.array([start, start]), np.array([start + 90 * NS, start]))
    np.testing.assert_array_equal(off, [90.0, MIN_OFFSET_S])


def test_sample_inputs_average_the_bins_of_the_span_before_the_sample():
    n_bins, bin_ns = 10, 60 * NS
    bins = np.tile(np.arange(n_bins, dtype=float)[:, None], (1, 7))  # bin k holds k
    bins[4, 1] = np.nan  # a bad value is left out of the mean
    u = np.full(8, -1.0)
    # a sample at 300 s with a 180 s span sees the bins (120, 300]: 2, 3 and 4
    got = sample_inputs_from_bins(bins, 0, bin_ns, u, 300 * NS, 180 * NS)
    assert got[0] == pytest.approx(3.0)
    assert got[1] == pytest.approx(2.5)
    assert got[7] == -1.0  # the unmeasured inlet moisture is the window's
    # a sample on a bin boundary does not see the bin after it
    assert sample_inputs_from_bins(bins, 0, bin_ns, u, 60 * NS, 60 * NS)[0] == 0.0
    # no bins: the window's inputs
    np.testing.assert_array_equal(
        sample_inputs_from_bins(np.empty((0, 7)), 0, bin_ns, u, 300 * NS, 180 * NS), u)
