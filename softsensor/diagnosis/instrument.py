"""Whether the baseline's residuals allow an offset on one thermometer at all.

An offset on one outlet thermometer moves that channel's residual and no other: the
model runs on the measured ``T_air_in``, so whatever the loop did with a wrong reading, the
other thermometer and the labs follow the process the model computes. One residual pattern
rules an offset on channel ``c`` out before its evidence counts (:func:`offset_contradiction`):

* **both thermometers off together**: the two channels' mean residuals over the same hours
  have the same sign and the smaller is at least :data:`TOGETHER_SHARE` of the larger. The two
  outlets moving together is a process change (heat input, inlet moisture, the plant's day
  level), not an instrument: on a healthy day the residuals were -0.77 and -0.74 K and the
  dryer outlet thermometer was named at 0.917 (issue 48).

Which of the two thermometers is off is left to the whitened evidence: the raw means do not
say it. On independent plant 8101 a +4.5 K offset on the loop's own ``T_dryer_out`` (day
seed 201) left mean residuals of +1.95 K on ``T_dryer_out`` and -1.96 K on
``T_cyclone_out``: the loop ran the process colder, the measured ``T_air_in`` carried that
into the model, and the model's response to it differs from the plant's on both outlets. A
rule naming the channel with the larger raw mean named the cyclone thermometer there (it was
tried and removed).

The loop's own thermometer, ``T_dryer_out``, gets its own words (:mod:`softsensor.
presentation.verdicts`): the loop holds its *reading* at the set point, so an offset on it
moves the process the other way, which the measured ``T_air_in`` carries into the model;
a model whose response to ``T_air_in`` is not the plant's then misses both outlets, in
opposite directions (above), not in the same one. A signature of its own for that (the
model's response to the loop's move) is not built.
"""

from __future__ import annotations

import math

import numpy as np

from softsensor.diagnosis.problem import Problem
from softsensor.signals import KELVIN_CHANNELS

#: The smaller of the two thermometers' mean residuals at least this share of the larger,
#: with the same sign: both off together, a process change.
TOGETHER_SHARE = 0.5


def residual_means(problem: Problem, onset_h: float = 0.0) -> np.ndarray:
    """Mean baseline residual of each outlet thermometer from ``onset_h`` on [K] (NaN
    where a channel has no value)."""
    r = problem.residuals(problem.baseline).T
    after = problem.windows.hours[: r.shape[0]] >= onset_h - 1e-9
    out = np.full(2, math.nan)
    for c in range(2):
        x = r[after, c]
        x = x[np.isfinite(x)]
        if x.size:
            out[c] = float(np.mean(x))
    return out


def offset_contradiction(problem: Problem, channel: str, onset_h: float = 0.0,
                         means: np.ndarray | None = None) -> str | None:
    """Why an offset on ``channel`` from ``onset_h`` on is ruled out (module docstring),
    in words; None when the residuals allow it. ``means``: :func:`residual_means` from
    ``onset_h``, when the caller has them."""
    m = residual_means(problem, onset_h) if means is None else means
    c = KELVIN_CHANNELS.index(channel)
    o = 1 - c
    if not (math.isfinite(m[c]) and math.isfinite(m[o])):
        return None
    other = KELVIN_CHANNELS[o]
    small, large = sorted((abs(m[c]), abs(m[o])))
    if m[c] * m[o] > 0 and small >= TOGETHER_SHARE * large:
        return (f"both thermometers are off together ({channel} {m[c]:+.2f} K, {other} "
                f"{m[o]:+.2f} K): a process change, not one instrument")
    return None


__all__ = ["TOGETHER_SHARE", "offset_contradiction", "residual_means"]
