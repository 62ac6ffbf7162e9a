"""Chunked model runs (``softsensor/calibration/chunked_run.py``): four chunks with the state
passed on give one run's outputs and cost, and several segments each start from their own
steady state."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_days import TRUTH

from softsensor.calibration.chunked_run import ChunkedRun, chunk_bounds, simulate_segments


def test_chunked_run_continues_the_state_exactly(model, segment, eq4):
    """Four chunks with the state passed on give the same outputs as one run; the partial
    cost after the last chunk is the full cost."""
    theta = np.stack([model.theta0, np.array(list(TRUTH.values()))])
    run = ChunkedRun(model, [segment], theta, eq4, n_chunks=4)
    assert list(run.bounds[0]) == list(chunk_bounds(segment.n_windows, 4))
    costs = []
    while not run.done:
        costs.append(run.advance())
    full = simulate_segments(model, [segment], theta)[0]
    np.testing.assert_allclose(run.runs[0].Y, full.Y, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(run.runs[0].lab, full.lab, rtol=1e-10, atol=1e-12)
    assert full.lab.shape == (2, len(segment.lab_value)) and np.isfinite(full.lab).all()
    final = run.run()
    assert [f.objective for f in final] == pytest.approx([costs[-1][0].objective,
                                                          costs[-1][1].objective])
    assert final[0].objective == final[0].fit.cost  # eq. 4 without a prior
    assert len(costs) == 4 and costs[0][0].fit.n["T_dryer_out"] == run.bounds[0][1] == 9
    assert final[0].fit.n["T_dryer_out"] == segment.n_windows == 36
    assert list(chunk_bounds(3, 4)) == [0, 1, 2, 3]


def test_chunked_run_over_two_segments_of_different_length(model, segment, eq4):
    """Several days or windows: each segment starts from its own steady state; the pooled
    cost equals eq. 4 over the concatenated residuals."""
    a, b = segment.slice(0, 20), segment.slice(20, 36)
    theta = np.array(list(TRUTH.values()))
    run = ChunkedRun(model, [a, b], theta[None], eq4, n_chunks=3)
    fit = run.run()[0].fit
    sep = simulate_segments(model, [a, b], theta)
    np.testing.assert_allclose(run.runs[1].Y, sep[1].Y, rtol=1e-10)
    assert fit.n["T_dryer_out"] == 36 and fit.n["moisture_out"] == len(segment.lab_value)
    one = simulate_segments(model, [segment], theta)[0]
    # the second segment restarts from a steady state: its first windows differ from the
    # continuous run, later ones converge as the wall forgets its start
    d = np.abs(sep[1].Y[0, :, 0] - one.Y[0, 20:, 0])
    assert d[-1] < d[0] or d[0] < 1e-6
