"""Covariance matching of single jumps (softsensor.estimation.jump_matching), on its own."""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.estimation.jump_matching import jumps, widen

#: Innovation covariance of two temperatures and a lab row, and sensitivities to three states:
#: 0 moves all three rows (an inlet-moisture step), 1 moves the temperatures alike with the
#: lab much less (a heat-input step), 2 one thermometer.
S = np.array([[0.30, 0.20, 0.001], [0.20, 0.30, 0.001], [0.001, 0.001, 4e-5]])
H = {0: np.array([-28.0, -27.0, 0.63]), 1: np.array([0.32, 0.31, -0.0031]),
     2: np.array([1.0, 0.0, 0.0])}
LIMITS = {0: 3.0, 1: 3.0, 2: 3.0}


def _t(state: int, S_: np.ndarray, nu: np.ndarray) -> float:
    h = H[state]
    w = np.linalg.solve(S_, h)
    return float(w @ nu) / float(np.sqrt(h @ w))


def test_a_jump_far_beyond_its_threshold_is_widened_to_one_standard_deviation():
    """After widening, the innovation's component along the jump taken is one standard
    deviation under the new innovation covariance ``S + dP_ii h h'``."""
    nu = 6.0 * np.sqrt(S[0, 0]) * np.array([1.0, 0.0, 0.0])   # one thermometer stepped
    P = np.diag([0.01, 10.0, 0.25])
    found = jumps(H, S, nu)
    P_new, taken = widen(P, found, LIMITS, preferred=0)
    assert [c.state for c in taken] == [2]
    grown = P_new[2, 2] - P[2, 2]
    assert grown > 0 and np.count_nonzero(P_new - P) == 1
    S_new = S + grown * np.outer(H[2], H[2])
    assert abs(_t(2, S_new, nu)) == pytest.approx(1.0, rel=1e-10)


def test_within_the_threshold_nothing_changes_and_look_alikes_go_to_the_preferred_state():
    P = np.diag([0.01, 10.0, 0.25])
    small = 0.5 * np.sqrt(np.diag(S)) * np.array([1.0, 1.0, 0.0])
    P_same, taken = widen(P, jumps(H, S, small), LIMITS, preferred=0)
    assert taken == [] and P_same is P
    # both temperatures up alike, the lab as a heat-input step would move it: the heat input
    # explains it best, but the inlet moisture's jump looks the same to the temperatures
    nu = 40.0 * H[1]
    found = jumps(H, S, nu)
    best = max(found, key=lambda c: abs(c.t))
    cos = abs(found[0].h @ best.w) / np.sqrt(found[0].info * best.info)
    assert best.state == 1 and cos > 0.95 and abs(found[0].t) > LIMITS[0]
    _, taken = widen(P, found, LIMITS, preferred=0)
    assert [c.state for c in taken] == [0]
    _, taken = widen(P, found, LIMITS, preferred=2)       # no look-alike preferred: the best
    assert [c.state for c in taken] == [1]
