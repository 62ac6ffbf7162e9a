"""Closed-loop design of experiments (``softsensor/calibration/experiment_design.py``, issue 15):
limits, the moisture bound with the plant's PI in the loop, the criterion against natural
operation, sequential designs. The ``design`` verb and its model loop:
``tests/apps/test_design.py``."""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.apps.design import DEFAULT_NOISE, OperatingPoint, build_problem
from softsensor.calibration.experiment_design import (
    DesignLimits,
    constant_levels,
    evaluate_levels,
    natural_candidate,
    optimise,
    schedule_from_levels,
)
from softsensor.calibration.settings import calibration_settings
from softsensor.plant.day import DEFAULT_START_NS

#: A short period keeps the tests fast: 2 h, moves of 30 min.
LIMITS = DesignLimits(T_sp_band=(347.0, 349.5), m_air_band=(79.0, 85.0), T_sp_rate=0.4,
                      m_air_rate=1.0, moisture_excursion=0.008, hours=2.0, move_minutes=30.0,
                      lab_minutes=20.0)


@pytest.fixture(scope="module")
def problem(cfg):
    op = OperatingPoint(cfg.nominal_inputs(), float(cfg.nominal.T_sp), DEFAULT_START_NS, None,
                        "nominal")
    return build_problem(cfg, cfg, op, LIMITS, calibration_settings(cfg), DEFAULT_NOISE)


def test_schedule_never_leaves_its_limits():
    rng = np.random.default_rng(3)
    for _ in range(20):
        # levels far outside [-1, 1] and a start at the band's edge: clipping must hold
        lv = rng.uniform(-3, 3, size=(2, LIMITS.n_moves))
        s = schedule_from_levels(lv, LIMITS, 349.5, 79.0, 20.0)
        assert s.T_sp.min() >= 347.0 - 1e-12 and s.T_sp.max() <= 349.5 + 1e-12
        assert s.m_air.min() >= 79.0 - 1e-12 and s.m_air.max() <= 85.0 + 1e-12
        assert np.max(np.abs(np.diff(s.T_sp))) <= LIMITS.T_sp_rate / 60 * 20.0 + 1e-9
        assert np.max(np.abs(np.diff(s.m_air))) <= LIMITS.m_air_rate / 60 * 20.0 + 1e-9
        assert s.t[-1] == pytest.approx(2 * 3600.0)


def test_limits_check_names_the_bad_limit():
    assert LIMITS.check(348.0, 82.0) is None
    bad = DesignLimits(T_sp_band=(350.0, 346.0), m_air_band=(79.0, 85.0))
    assert "T_sp band" in bad.check()
    assert "outside" in LIMITS.check(352.0, 82.0)


def test_moisture_bound_is_met_with_the_pi_in_the_loop(problem):
    natural, baseline = natural_candidate(problem)
    # the plant's PI holds the outlet temperature at a constant set point
    assert np.max(np.abs(natural.prediction.Y[:, 0] - 348.0)) < 0.05
    full = np.array([[1.0, -1.0, 1.0, -1.0], [1.0, -1.0, -1.0, 1.0]])
    cand = evaluate_levels(problem, full, baseline)
    assert cand.feasible
    # the excursion is measured on the closed-loop prediction and within its bound
    exc = np.max(np.abs(cand.prediction.Y[:, 2] - baseline))
    assert exc == pytest.approx(cand.excursion)
    assert exc <= LIMITS.moisture_excursion
    # the full-amplitude moves exceed it, so the bound was enforced by shrinking them
    assert cand.shrink < 1.0
    # the flaps follow the set point: the loop, not an open-loop model, made the prediction
    assert np.ptp(cand.prediction.U[:, 0]) > 1.0
    big = problem.loop.run(schedule_from_levels(full, LIMITS, 348.0, 82.0, problem.loop.dt),
                           problem.theta)
    assert np.max(np.abs(big.Y[:, 2] - baseline)) > LIMITS.moisture_excursion


def test_design_beats_the_constant_schedule(problem):
    res = optimise(problem, seed=0, n_random=3, budget=6)
    assert res.best.feasible and res.best.excursion <= LIMITS.moisture_excursion
    assert res.best.score > res.natural.score + 5.0
    assert res.best.info.condition < res.natural.info.condition
    lo, hi = LIMITS.T_sp_band
    assert lo <= res.best.schedule.T_sp.min() and res.best.schedule.T_sp.max() <= hi
    home = constant_levels(LIMITS, 348.0, 82.0)
    assert not np.allclose(res.best.schedule.levels, home)


def test_sequential_designs_at_each_new_estimate():
    from types import SimpleNamespace

    from softsensor.calibration.experiment_design import Information, sequential

    seen, recorded = [], []

    def design_at(theta):
        seen.append(theta.copy())
        return SimpleNamespace(best=SimpleNamespace(schedule=f"s{len(seen)}", score=1.0))

    def record(schedule, r):
        recorded.append((schedule, r))
        return schedule

    def recalibrate(segments, theta):
        return theta * 2.0 if len(segments) == len(recorded) else theta

    def assess(segments, theta):
        se = np.full(7, 1.0 / len(segments))
        return Information(np.eye(7), 0.0, 1.0, np.diag(se**2), se, 0.0)

    rounds = sequential(design_at, record, recalibrate, assess, np.ones(7), 3)
    assert [r[1] for r in recorded] == [0, 1, 2]
    assert [float(t[0]) for t in seen] == [1.0, 2.0, 4.0]  # each round designs at the new one
    assert [float(r.se[0]) for r in rounds] == [1.0, 0.5, 1.0 / 3]  # on all periods so far
