"""The polish after the study (``softsensor/calibration/refine.py``): it lowers eq. 4 within
the bounds, in a bounded number of model runs."""

from __future__ import annotations

import numpy as np

from softsensor.calibration.refine import refine


def test_polish_lowers_the_cost_within_bounds(model, segment, config, eq4):
    start = np.array([0.3, 0.5, 3.0, 1.0, 4.0, 1e-5, 30.0])
    bounds = config.bounds()
    bounds[4, 1] = 4.5  # a tight upper bound on mult_p: the polish must respect it
    r = refine(model, [segment], start, bounds, eq4)
    assert r.improved and r.evaluation.fit.cost < 0.6 * r.start.fit.cost
    assert np.all(r.theta >= bounds[:, 0]) and np.all(r.theta <= bounds[:, 1])
    assert r.simulations <= 100  # two passes of at most 6 evaluations of 1 + 7 members
