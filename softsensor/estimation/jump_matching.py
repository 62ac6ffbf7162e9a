"""Covariance matching of single jumps: the one state whose step best explains an innovation.

A new pile of chips steps the inlet moisture, a thermometer that drifts or is replaced steps
its channel's offset: faster than any process noise a filter can carry without becoming
useless in between. Before its update the filter asks whether the innovation says that one
state jumped (covariance matching, Mehra 1972) and, if so, widens that state's prior variance
so the update takes the jump at once.

For each candidate state ``i``, with ``h = dz / dx_i`` the sensitivity of the measurements to
that state alone (the others held), ``S`` the innovation covariance and ``nu`` the innovation,
``t_i = h' S^-1 nu / sqrt(h' S^-1 h)`` is the innovation's component along what a jump of
``x_i`` would do, in standard deviations, and ``t_i^2`` the drop of the normalised innovation
squared that such a jump buys (a generalised likelihood ratio). The candidate with the largest
``|t_i|`` is the best single explanation: a step of the inlet moisture moves both temperatures
(and the lab) as the model says, a thermometer that steps moves one channel. When its ``|t|``
exceeds its threshold, ``P_ii`` grows by ``(t^2 - 1) / (h' S^-1 h)``, after which that
component is one standard deviation. Taking one jump, the best, keeps a single thermometer's
step from being read as an inlet-moisture step plus the other thermometer's opposite offset.

Jumps whose effects on the measurements have a cosine above :data:`SAME_JUMP` (``S^-1``
metric) cannot be told apart by them (an inlet-moisture step and a heat-input step both move
the two temperatures together). Among those the caller's ``preferred`` state takes the jump:
for the estimator the inlet moisture, the one that steps (the heat input's error drifts with
the conditions), and later lab results, which see it through the outlet moisture, confirm or
undo it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

#: Two jumps whose effects on the measurements have a cosine above this (``S^-1`` metric)
#: cannot be told apart by them.
SAME_JUMP = 0.95


class Jump(NamedTuple):
    """A candidate jump of one state: its index, the innovation's component along it in
    standard deviations ``t``, ``h' S^-1 h``, ``h`` and ``S^-1 h``."""

    state: int
    t: float
    info: float
    h: np.ndarray
    w: np.ndarray


def jumps(partials: dict[int, np.ndarray], S: np.ndarray, nu: np.ndarray) -> list[Jump]:
    """The candidate jumps, one per state in ``partials`` (``state -> h``, the measurements'
    sensitivity to it alone) that the measurements can see at all (``h' S^-1 h > 0``)."""
    found = []
    for i, h in partials.items():
        w = np.linalg.solve(S, h)
        info = float(h @ w)
        if info > 0:
            found.append(Jump(i, float(w @ nu) / math.sqrt(info), info, h, w))
    return found


def widen(P: np.ndarray, found: list[Jump], threshold: dict[int, float], preferred: int
          ) -> tuple[np.ndarray, list[Jump]]:
    """``P`` with the variance of the jump taken grown until its ``t`` is one standard
    deviation, and the jumps taken (``P`` itself and ``[]`` when the best candidate's ``|t|``
    is within its ``threshold``; module docstring)."""
    if not found:
        return P, []
    best = max(found, key=lambda c: abs(c.t))
    if abs(best.t) <= threshold[best.state]:
        return P, []
    alike = [c for c in found
             if c.state == preferred and abs(c.h @ best.w) / math.sqrt(c.info * best.info)
             > SAME_JUMP and abs(c.t) > threshold[c.state]]
    taken = alike or [best]
    P = P.copy()
    for c in taken:
        P[c.state, c.state] += (c.t * c.t - 1.0) / c.info
    return P, taken


__all__ = ["SAME_JUMP", "Jump", "jumps", "widen"]
