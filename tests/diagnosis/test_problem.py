"""The diagnosis problem (``softsensor/diagnosis/problem.py``): lab results met at their
sample time, the split into a fitted and a held-out part and its reverse."""

from __future__ import annotations

import numpy as np
from diagnosis_problem import make_problem

from softsensor.diagnosis.day_windows import day_windows
from softsensor.diagnosis.problem import choose_split


def test_lab_points_move_with_the_sample_time(cfg, model, day):
    """A lab result meets the model at its sample time: moving every sample time by one
    window gives the model's values one window later."""
    p = make_problem(cfg, model, day)
    W = p.windows.window_s
    here = p.lab_points()
    later = p.lab_points(shift_ns=W * 1e9)
    assert np.all(later.window[here.window + 1 < p.windows.n_windows]
                  == here.window[here.window + 1 < p.windows.n_windows] + 1)
    # the baseline at the unmoved points is the baseline's own lab prediction
    np.testing.assert_allclose(p.baseline_labs(here), p.baseline.lab, rtol=0, atol=1e-9)


def test_the_reversed_split_swaps_the_parts(cfg, model, day):
    p = make_problem(cfg, model, day)
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


def test_problem_split_keeps_labs_on_both_sides(cfg, day):
    w = day_windows(day, cfg)
    s = choose_split(w, min_labs=2)
    assert s.lab_fit.sum() >= 2 and s.lab_held.sum() >= 2
    assert 0.5 * w.n_windows <= s.k_fit <= 0.7 * w.n_windows
    assert np.all(w.lab_time_ns[s.lab_fit] < s.split_ns)
    assert s.split_ns == w.end_ns[s.k_fit - 1]
