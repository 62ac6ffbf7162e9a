"""The eq. 4 cost (``softsensor/calibration/cost.py``) recomputed by hand on a day whose window
means are known: per-channel RMSE, the weighted sum, the partial cost up to a window, pooled
segments, a failed run's infinite cost, a batch of runs. Pure numpy, no model runs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from synthetic_days import NS, T0, make_day

from softsensor.calibration.cost import ModelRun, evaluate_fit, residuals
from softsensor.calibration.dataset import segment_from_day


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
