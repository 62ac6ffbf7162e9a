"""A probability for every cause, and "cannot tell" where the day cannot tell two apart.

Every candidate gets a log-evidence ``L`` in nats against the unextended model, from the
penalised held-out log-likelihood gains of :mod:`.verdict` (``P``, already less one nat per
fitted parameter), and the probabilities are a softmax ``exp(L / T) / sum exp(L_j / T)``:

=================== =======================================================================
candidate           ``L``
=================== =======================================================================
eligible extension  ``P - MIN_PENALISED``: an extension is charged the gain a clean day's
                    best extension reaches against the approximate normal
                    (``MIN_PENALISED``, :mod:`.verdict`)
other extension     ``min(P - MIN_PENALISED, 0) - INELIGIBLE_PENALTY``: a failed check
                    (worse channel, no eq. 4 gain) costs it this much more, whatever ``P``
skipped extension   ``-MIN_PENALISED - INELIGIBLE_PENALTY``: the residuals rule it out before
                    any fit (as a fit that gains nothing)
``none``            ``-max(s, 0)``
``unexplained``     ``min(s, 0)``
=================== =======================================================================

``s`` is the baseline's structure margin (:func:`~.verdict.structure_margins`, the largest
over the channels): what the whitened residuals hold beyond what ``unexplained`` is charged,
``STRUCTURE_MS`` times their count, half of it in log-likelihood. It is positive exactly when
the verdict calls the residuals structured, so ``none`` and ``unexplained`` each pay for what
the other explains, and ``unexplained`` carries the largest penalty of all candidates.

The most probable candidate is the verdict's cause by construction: the winner is the
eligible extension with the largest ``P`` (``L >= 0``), every other eligible one a smaller
``L`` and every ineligible or skipped one ``L < 0``, and the unextended candidate the
verdict falls back on has ``L = 0``.

The temperature ``T`` (:data:`TEMPERATURE`) is fitted on tuning days only (the minimum of the
mean Brier score, :func:`fit_temperature`), never on the days it is judged on.

**Cannot tell** (:func:`cannot_tell`): when the two most probable candidates are extensions
whose probabilities are within a factor of :data:`CANNOT_TELL_ODDS` and whose signatures on
this day (:mod:`.detectability`) are nearly collinear (``|cos| >= COLLINEAR``), the data of
the day do not tell them apart: the report names both instead of the larger alone.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from softsensor.diagnosis.detectability import Signature, collinearity
from softsensor.diagnosis.verdict import MIN_PENALISED, Score, Verdict

#: What a failed eligibility check costs an extension beyond the charge of an eligible one.
#: [nats] Three, the size of the verdict's ``WORSE`` allowance: an extension that fails a
#: check stays a candidate (its cause may be there, below what the day shows), but below the
#: unextended model.
INELIGIBLE_PENALTY = 3.0
#: Temperature of the softmax. Fitted on tuning days, never on fresh ones
#: (:func:`fit_temperature`: ``benchmarks/diagnosis_temperature.py``, independent plant seed
#: 11, its normal from 4 clean 16 h days, 16 test days of 16 h, 2 per cause, day seeds 300 to
#: 315; ``benchmarks/results/diagnosis_temperature_plant11.json``): the Brier score's minimum is at
#: 7.96 (0.637; 0.793 at 1, 0.651 at 5, 0.649 at 13). It is that large because 7 of the 16
#: days were missed with the true cause's log-evidence 3 to 81 nats down: a named ``none``
#: or ``unexplained`` was right on 5 of 11 days, so a clean day's ``none`` gets about 0.5.
TEMPERATURE = 8.0
#: Two candidates whose probabilities are within this factor ...
CANNOT_TELL_ODDS = 3.0
#: ... and whose signatures on the day have ``|cos|`` at least this cannot be told apart.
COLLINEAR = 0.9


@dataclass(frozen=True)
class Candidate:
    """One cause (and sensor, for an offset) with its log-evidence and probability."""

    cause: str
    channel: str | None
    log_evidence: float
    probability: float

    def to_json(self) -> dict[str, object]:
        return {"cause": self.cause, "channel": self.channel,
                "probability": round(self.probability, 6),
                "log_evidence": round(self.log_evidence, 3)}


def log_evidence(scores: Iterable[Score], skipped: Iterable[str],
                 structure: float) -> list[tuple[str, str | None, float]]:
    """``(cause, channel, L)`` of every candidate (module docstring); ``structure`` is the
    structure margin ``s`` (``-inf`` when no channel has values)."""
    out: list[tuple[str, str | None, float]] = []
    for sc in scores:
        gain = sc.penalised - MIN_PENALISED
        L = gain if sc.eligible else min(gain, 0.0) - INELIGIBLE_PENALTY
        out.append((sc.cause, sc.channel, L if math.isfinite(L) else -math.inf))
    out += [(c, None, -MIN_PENALISED - INELIGIBLE_PENALTY) for c in skipped]
    s = structure if math.isfinite(structure) else -math.inf
    out.append(("none", None, -max(s, 0.0)))
    out.append(("unexplained", None, min(s, 0.0)))
    return out


def softmax(L: np.ndarray, temperature: float) -> np.ndarray:
    """``exp(L / T)`` normalised (``-inf`` gets 0)."""
    z = np.asarray(L, float) / temperature
    z = z - np.max(z)
    e = np.exp(z)
    return e / e.sum()


def posterior(verdict: Verdict, scores: Iterable[Score], skipped: Iterable[str],
              structure: float, temperature: float = TEMPERATURE) -> list[Candidate]:
    """Every candidate with its probability, most probable first (the verdict's cause first
    among equals)."""
    ev = log_evidence(scores, skipped, structure)
    p = softmax(np.array([e[2] for e in ev]), temperature)
    cands = [Candidate(c, ch, L, float(q)) for (c, ch, L), q in zip(ev, p, strict=True)]
    return sorted(cands, key=lambda c: (-c.probability, c.cause != verdict.cause))


def cannot_tell(cands: Sequence[Candidate], sigs: Mapping[str, Signature],
                odds: float = CANNOT_TELL_ODDS, collinear: float = COLLINEAR
                ) -> dict[str, object] | None:
    """The two most probable candidates when this day cannot tell them apart (module
    docstring): ``{"causes": [...], "collinearity": |cos|}``, else None."""
    if len(cands) < 2:
        return None
    a, b = cands[0], cands[1]
    if a.cause not in sigs or b.cause not in sigs:
        return None
    if not b.probability > 0 or a.probability / b.probability > odds:
        return None
    cos = collinearity(sigs[a.cause], sigs[b.cause])
    if cos < collinear:
        return None
    return {"causes": [a.to_json(), b.to_json()], "collinearity": round(cos, 4)}


def fit_temperature(days: Sequence[tuple[Sequence[float], int]],
                    bounds: tuple[float, float] = (0.05, 100.0)) -> float:
    """The temperature minimising the mean Brier score ``sum_c (p_c - y_c)^2`` over ``days``,
    each ``(L of every candidate, index of the true one, -1 when none is)`` (searched on the
    log scale). The Brier score, not the log loss: on tuning days where the true cause left
    no trace (its fit failed, ``L`` tens of nats down) the log loss is ruled by those days
    alone and flattens every probability (it chose ``T = 93`` on the tuning days); the Brier
    score is bounded and is the issue's measure."""
    if not days:
        raise ValueError("fit_temperature: no days")

    def loss(log_t: float) -> float:
        t = math.exp(log_t)
        out = []
        for L, i in days:
            p = softmax(np.asarray(L, float), t)
            y = np.zeros_like(p)
            if i >= 0:
                y[i] = 1.0
            out.append(float(np.sum((p - y) ** 2)) + (1.0 if i < 0 else 0.0))
        return float(np.mean(out))

    res = minimize_scalar(loss, bounds=tuple(math.log(b) for b in bounds), method="bounded",
                          options={"xatol": 1e-3})
    return float(math.exp(res.x))
