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
a cause's shape     ``log B - SHAPE_CHARGE - max(s_left, 0)`` (:mod:`.shapes`: the marginal
                    evidence of the shape it leaves on the residuals, Occam factor included,
                    charged as an extension is and paying for the structure ``s_left`` it
                    leaves); the cause takes the larger of this and its extension's ``L``
=================== =======================================================================

``s`` is the baseline's structure margin (:func:`~.verdict.structure_margins`, the largest
over the channels): what the whitened residuals hold beyond what ``unexplained`` is charged,
``STRUCTURE_MS`` times their count, half of it in log-likelihood. It is positive exactly when
the verdict calls the residuals structured, so ``none`` and ``unexplained`` each pay for what
the other explains, and ``unexplained`` carries the largest penalty of all candidates.

When a shape's ``L`` is the largest of all, its cause is named (the verdict's ranking
puts it first, :func:`~.diagnose_day.named_by_shape`): a cause whose model extension failed
on a plant whose form of it is not the model's is still named by what it leaves. When that
cause is already the verdict's, named by its eligible extension, the extension stays the
verdict, held-out gain and all (:func:`~.diagnose_day.after_shapes`).

The probabilities read the log-evidences as the likelihood of a model that is itself only
approximately right: with a prior ``pi`` over the candidates (uniform: before the day is seen,
every candidate is as likely as any other; a sensor offset on the channel its fit chose) and
a share ``eps`` of days on which the evidence misleads (the calibrated model's own error, a
fit caught in a wrong optimum, a cause whose fit found nothing), the probability of
candidate ``c`` is

    ``p_c = (1 - eps) exp(L_c / T) / sum_j exp(L_j / T) + eps pi_c``

The temperature ``T`` (:data:`TEMPERATURE`) says how many nats of the penalised gains are
one nat of real evidence on a plant the model is not; ``eps`` (:data:`CONTAMINATION`) bounds
what any evidence can claim: however many nats a fit gains, its probability stays at or
below ``1 - eps (1 - pi_c)``. ``eps`` is one of three values, by what the day's evidence
names (:func:`kind`): an eligible extension or a shape (a fitted cause that explains the day
beyond the normal), ``none`` or ``unexplained``; the last two were right far less often on
the tuning days (a cause whose fit failed lands there). The three values and ``T`` are
fitted together on tuning days only, at the minimum of the mean Brier score
(:func:`fit_calibration`), and checked on fresh ones with a reliability table
(``benchmarks/diagnosis_temperature.py``, docs/results/diagnosis.md). The mixture is
monotone in ``L`` within a day, so the most probable candidate is still the verdict's cause:
the winner is the eligible extension with the largest ``P`` (``L >= 0``), every other
eligible one a smaller ``L`` and every ineligible or skipped one ``L < 0``, and the
unextended candidate the verdict falls back on has ``L = 0``; a shape named instead is the
candidate of largest ``L``.

The extensions' ``P`` charges one nat per parameter (Akaike); the shapes carry their exact
Occam factor (a linear-Gaussian evidence, :func:`~.shapes.linear_evidence`). The temperature
and ``eps`` carry what either misjudges, measured on tuning days.

**Cannot tell** (:func:`cannot_tell`): when the most probable candidate is less than
:data:`CANNOT_TELL_ODDS` times as likely as the second on the day's evidence
(``exp((L_1 - L_2) / T)``, :func:`undecided`), the evidence does not separate them,
whichever they are (``none`` and ``unexplained`` included: a lab delay
against ``unexplained`` is the commonest such pair). The report names both, says what data
would separate them (:data:`WHAT_SHOWS`: the operation under which each cause leaves a trace
the other does not) and, for two extensions, how collinear their signatures on this day are
(:mod:`.detectability`; ``|cos|`` near 1: both leave the same trace).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from softsensor.diagnosis.detectability import Signature, collinearity
from softsensor.diagnosis.plant_normal import PlantNormal
from softsensor.diagnosis.settings import DiagnosisSettings
from softsensor.diagnosis.shapes import ShapeFit
from softsensor.diagnosis.verdict import MIN_PENALISED, Score, Verdict

#: What a failed eligibility check costs an extension beyond the charge of an eligible one.
#: [nats] Three, the size of the verdict's ``WORSE`` allowance: an extension that fails a
#: check stays a candidate (its cause may be there, below what the day shows), but below the
#: unextended model.
INELIGIBLE_PENALTY = 3.0
#: Temperature of the softmax and share of days on which the evidence misleads, by kind of
#: verdict (module docstring). Fitted together on tuning days only (:func:`fit_calibration`,
#: the minimum of the mean Brier score): ``benchmarks/diagnosis_temperature.py --refit`` over
#: independent plants 11 and 12 (each its normal from 4 clean 16 h days, day seeds 100 to
#: 103; 16 test days of 16 h, 2 per cause, day seeds 300 to 315, diagnosed with the shapes of
#: :mod:`.shapes`; ``benchmarks/results/diagnosis_calibration.json``): ``T = 1.21``; of the 32
#: verdicts, 18 of 19 fitted causes were right (``eps`` 2/21 by the rule of succession: a
#: cause named with hundreds of nats gets about 0.92), 4 of 5 ``none`` (2/7 likewise, 0.74)
#: and 4 of 8 ``unexplained`` (the Brier minimum 0.5, 0.52). What the probabilities mean comes
#: from ``eps``. Checked on fresh plants 7001 to 7004 with a reliability table
#: (docs/results/diagnosis.md).
TEMPERATURE = 1.21
CONTAMINATION = {"extension": 0.095, "none": 0.286, "unexplained": 0.5}
#: What a shape (:mod:`.shapes`) is charged beyond its Occam factor before it competes. [nats]
#: Chosen on the tuning plants 11 and 12 (below), where it came out at the value of the
#: verdict's ``MIN_PENALISED`` (the gain a clean day's best extension reaches against the
#: approximate normal); its own number, so that moving the verdict's threshold does not move
#: the shapes' charge without a new check. Checked on the 32 days of tuning plants 11 and 12 only
#: (``benchmarks/diagnosis_temperature.py --shapes``, then ``--refit``; the tuning days'
#: Brier at the refitted temperature and contamination): 0.32 at 5, 0.290 at 8, 0.286 at
#: 10, 0.289 at 12, 0.32 at 15. The clean tuning days' largest shape evidence is 5.4 nats (a
#: thermometer step, plant 12, seed 300); there the fouling ramp reached 11.7 before it was
#: cut to a loss of transfer (every clean day's ramp fitted a gain).
SHAPE_CHARGE = 10.0
#: The most probable candidate less than this many times as probable as the second: the
#: day cannot tell them apart. Three: the leader holds under three quarters of what the two
#: share.
CANNOT_TELL_ODDS = 3.0
#: What data would show each cause apart from the others: the operation under which it
#: leaves a trace no other cause leaves (the shapes of :mod:`.extensions`).
WHAT_SHOWS = {
    "none": "a longer record of the same operation (a real cause grows clearer with more "
            "data, the model's noise does not)",
    "inlet_moisture": "lab results while both outlet temperatures move together at steady "
                      "load (an inlet change moves both temperatures and the lab moisture "
                      "through the energy balance)",
    "sensor_bias": "a change of production rate (an offset keeps its size while the process "
                   "moves; a process change does not)",
    "lab_delay": "lab samples taken while the outlet moisture moves, just after a production "
                 "change (a shifted sample time shows only then)",
    "fouling_drift": "a longer record with a load change (a transfer drift grows with time "
                     "and its effect scales with the load)",
    "input_lag": "a step of T_air_in (a flap or set-point move; a lag shows only while "
                 "T_air_in moves)",
    "ambient_heat_loss": "a day with an ambient temperature swing of 10 K or more",
    "unexplained": "more clean history days (a normal that sizes the model's own wander "
                   "better)",
}


@dataclass(frozen=True)
class Candidate:
    """One cause (and sensor, for an offset) with its log-evidence and probability."""

    cause: str
    channel: str | None
    log_evidence: float
    probability: float
    #: Where ``log_evidence`` comes from: ``"extension"`` (:mod:`.verdict`'s scores),
    #: ``"shape"`` (:mod:`.shapes`) or ``"baseline"`` (``none``, ``unexplained``).
    source: str = "extension"

    def to_json(self) -> dict[str, object]:
        return {"cause": self.cause, "channel": self.channel,
                "probability": round(self.probability, 6),
                "log_evidence": round(self.log_evidence, 3), "source": self.source}


def shape_evidence(fit: ShapeFit, charge: float = SHAPE_CHARGE) -> float:
    """A shape's log-evidence ``log B - charge - max(structure left, 0)`` (:mod:`.shapes`):
    charged as an extension is, and paying for what it leaves structured as ``none``
    does."""
    L = fit.log_bayes - charge - max(fit.structure_left, 0.0)
    return L if math.isfinite(L) else -math.inf


def log_evidence(scores: Iterable[Score], skipped: Iterable[str], structure: float,
                 shapes: Iterable[ShapeFit] = ()) -> list[tuple[str, str | None, float, str]]:
    """``(cause, channel, L, source)`` of every candidate (module docstring); ``structure``
    is the structure margin ``s`` (``-inf`` when no channel has values). A cause with a
    shape (:mod:`.shapes`) takes the larger of its extension's ``L`` and the shape's
    (:func:`shape_evidence`; ``source`` says which: ``"extension"`` or ``"shape"``), with the
    shape's channel when the shape's is larger."""
    out: list[tuple[str, str | None, float, str]] = []
    for sc in scores:
        gain = sc.penalised - MIN_PENALISED
        L = gain if sc.eligible else min(gain, 0.0) - INELIGIBLE_PENALTY
        out.append((sc.cause, sc.channel, L if math.isfinite(L) else -math.inf, "extension"))
    out += [(c, None, -MIN_PENALISED - INELIGIBLE_PENALTY, "extension") for c in skipped]
    s = structure if math.isfinite(structure) else -math.inf
    out.append(("none", None, -max(s, 0.0), "baseline"))
    out.append(("unexplained", None, min(s, 0.0), "baseline"))
    return with_shapes(out, shapes)


def with_shapes(candidates: Sequence[tuple[str, str | None, float, str]],
                shapes: Iterable[ShapeFit]) -> list[tuple[str, str | None, float, str]]:
    """``candidates`` (``(cause, channel, L, source)``) with each cause's ``L`` the larger of
    its own and its shape's (:func:`shape_evidence`), the shape's channel and ``"shape"`` as
    the source where the shape's is larger."""
    out = list(candidates)
    for fit in shapes:
        L = shape_evidence(fit)
        for i, (c, _, L_ext, _) in enumerate(out):
            if c == fit.cause and L > L_ext:
                out[i] = (c, fit.channel, L, "shape")
    return out


def softmax(L: np.ndarray, temperature: float) -> np.ndarray:
    """``exp(L / T)`` normalised (``-inf`` gets 0)."""
    z = np.asarray(L, float) / temperature
    z = z - np.max(z)
    e = np.exp(z)
    return e / e.sum()


def kind(cause: str) -> str:
    """Which of :data:`CONTAMINATION`'s values a day whose evidence names ``cause`` takes:
    ``none``, ``unexplained`` or ``extension`` (any fitted cause)."""
    return cause if cause in ("none", "unexplained") else "extension"


def probabilities(L: np.ndarray, temperature: float = TEMPERATURE,
                  contamination: float = CONTAMINATION["extension"]) -> np.ndarray:
    """``p = (1 - eps) softmax(L / T) + eps / n`` (module docstring; the uniform prior)."""
    p = softmax(L, temperature)
    return (1.0 - contamination) * p + contamination / p.size


def posterior(verdict: Verdict, scores: Iterable[Score], skipped: Iterable[str],
              structure: float, temperature: float = TEMPERATURE,
              contamination: Mapping[str, float] = CONTAMINATION,
              shapes: Iterable[ShapeFit] = (), normal: PlantNormal | None = None,
              settings: DiagnosisSettings | None = None) -> list[Candidate]:
    """Every candidate with its probability, most probable first (the named cause first
    among equals).

    With a plant ``normal`` of at least two history days the probabilities are judged
    against it (:func:`normal_probabilities`, the prior of ``settings``); without one, by
    the fallback softmax at ``temperature`` with ``contamination`` by :func:`kind` of the
    named cause (the verdict's, or the cause whose shape, :mod:`.shapes`, has the largest
    log-evidence of all): constants fitted on the virtual plant, a fallback only. With fewer
    history days than ``settings.min_history_days`` no cause is given more than
    ``settings.cap_without_history`` (:func:`capped`)."""
    settings = settings or DiagnosisSettings()
    ev = log_evidence(scores, skipped, structure, shapes)
    L = np.array([e[2] for e in ev])
    leader = ev[int(np.argmax(L))]
    named = leader[0] if leader[3] == "shape" else verdict.cause
    if normal is not None and normal.n_days >= 2:
        p = normal_probabilities(ev, normal, settings.healthy_base_rate)
    else:
        p = probabilities(L, temperature, contamination[kind(named)])
    i_none = [e[0] for e in ev].index("none")
    if normal is None or normal.n_days < settings.min_history_days:
        p = capped(p, i_none, settings.cap_without_history)
    causes = [e[0] for e in ev]
    if p[causes.index(named)] < float(np.max(p)) - 1e-12:
        named = causes[int(np.argmax(p))]
    cands = [Candidate(c, ch, Lc, float(q), src)
             for (c, ch, Lc, src), q in zip(ev, p, strict=True)]
    return sorted(cands, key=lambda c: (-c.probability, c.cause != named))


def normal_probabilities(ev: Sequence[tuple[str, str | None, float, str]],
                         normal: PlantNormal, base_rate: float) -> np.ndarray:
    """Probabilities of the candidates ``ev`` (``(cause, channel, L, source)``, one of them
    ``none``) judged against the plant's normal (:mod:`.plant_normal`): each candidate's
    Bayes factor against ``none`` is the smaller of the model's own (``L - L_none``) and the
    largest one its tail probability among this plant's healthy history days can carry
    (:meth:`PlantNormal.log_bayes_bound <.plant_normal.PlantNormal.log_bayes_bound>`; a
    candidate the history never scored gets at most 1); the prior gives ``none``
    ``base_rate`` and shares the rest evenly, so ``p_c = pi_c B_c / sum_j pi_j B_j``."""
    causes = [e[0] for e in ev]
    L_none = ev[causes.index("none")][2]
    n_other = max(len(ev) - 1, 1)
    logp = np.empty(len(ev))
    for i, (c, _, L, _) in enumerate(ev):
        if c == "none":
            logp[i] = math.log(base_rate)
            continue
        e = L - L_none
        b = normal.log_bayes_bound(c, e)
        b = min(e, 0.0) if b is None else b
        logp[i] = math.log((1.0 - base_rate) / n_other) + (b if math.isfinite(b) else -math.inf)
    return softmax(logp, 1.0)


def capped(p: np.ndarray, i_none: int, cap: float) -> np.ndarray:
    """``p`` with no candidate but ``i_none`` above ``cap``: what is taken off is shared by
    the others in proportion to their probability (evenly where all of them are 0), until
    none is above (the order below the cap kept)."""
    p = np.asarray(p, float).copy()
    for _ in range(p.size):
        over = (p > cap + 1e-12)
        over[i_none] = False
        if not over.any():
            break
        excess = float(np.sum(p[over] - cap))
        p[over] = cap
        rest = ~over & (p < cap)
        rest[i_none] = True
        w = p[rest] if p[rest].sum() > 0 else np.ones(int(rest.sum()))
        p[rest] += excess * w / w.sum()
    return p / p.sum()


def separating_data(a: str, b: str) -> str:
    """What data would separate causes ``a`` and ``b`` (:data:`WHAT_SHOWS`), in words."""
    return "; ".join(f"for {c}, {WHAT_SHOWS[c]}" for c in (a, b) if c in WHAT_SHOWS)


def undecided(L_first: float, L_second: float, temperature: float = TEMPERATURE,
              odds: float = CANNOT_TELL_ODDS) -> bool:
    """Whether two log-evidences are within the evidence's resolution: the first less than
    ``odds`` times as likely as the second on the evidence alone (``exp((L1 - L2) / T)``;
    the contamination is the same for both and tells them no further apart)."""
    return (L_first - L_second) / temperature < math.log(odds)


def cannot_tell(cands: Sequence[Candidate], sigs: Mapping[str, Signature],
                odds: float = CANNOT_TELL_ODDS, temperature: float = TEMPERATURE,
                by_probability: bool = False) -> dict[str, object] | None:
    """The two most probable candidates when this day cannot tell them apart (module
    docstring, :func:`undecided`; with ``by_probability``, judged against the plant's
    normal, when the first is less than ``odds`` times as probable as the second):
    ``{"causes": [...], "collinearity": |cos| or None, "separate": words}``, else None.
    ``collinearity`` is given for two causes with signatures (None when either is ``none``
    or ``unexplained``)."""
    if len(cands) < 2:
        return None
    a, b = cands[0], cands[1]
    if by_probability:
        if not a.probability < odds * b.probability:
            return None
    elif not undecided(a.log_evidence, b.log_evidence, temperature, odds):
        return None
    cos = (round(collinearity(sigs[a.cause], sigs[b.cause]), 4)
           if a.cause in sigs and b.cause in sigs else None)
    return {"causes": [a.to_json(), b.to_json()], "collinearity": cos,
            "separate": separating_data(a.cause, b.cause)}


def brier(p: np.ndarray, i: int) -> float:
    """Brier score ``sum_c (p_c - y_c)^2`` of one day, ``i`` the true candidate's index (-1
    when no candidate is right: it then counts the missing one's 1 as well)."""
    y = np.zeros_like(p)
    if i >= 0:
        y[i] = 1.0
    return float(np.sum((p - y) ** 2)) + (1.0 if i < 0 else 0.0)


def fit_calibration(days: Sequence[tuple[Sequence[float], int, str]],
                    t_bounds: tuple[float, float] = (0.05, 100.0)
                    ) -> tuple[float, dict[str, float]]:
    """``(T, {kind: eps})`` minimising the mean Brier score over ``days``, each ``(L of every
    candidate, index of the true one or -1 when none is, kind of the named cause)``
    (:func:`kind`): each ``eps`` on a grid of 0.02 over [0, 0.9] (they are independent
    given ``T``: each kind's days have their own), ``T`` searched on the log scale. Each
    ``eps`` is at least ``(w + 1) / (N + 2)`` for ``w`` wrong verdicts among the kind's
    ``N`` days (Laplace's rule of succession, the mean wrong rate under a uniform prior):
    the Brier minimum on a dozen days can sit below what those days show (0 where none was
    wrong, 0.08 for the extensions' 1 wrong in 13), and a verdict's probability is at most
    ``1 - eps (1 - 1/n)``. The
    Brier score, not the log loss: on tuning days where the true cause left no trace (its fit
    failed, ``L`` tens of nats down) the log loss is ruled by those days alone and flattens
    every probability (it chose ``T = 93`` on the tuning days); the Brier score is bounded
    and is the issue's measure."""
    if not days:
        raise ValueError("fit_calibration: no days")
    n = max(len(L) for L, _, _ in days)
    Lm = np.full((len(days), n), -np.inf)
    Y = np.zeros((len(days), n))
    extra = np.zeros(len(days))
    for d, (L, i, _) in enumerate(days):
        Lm[d, :len(L)] = L
        if i >= 0:
            Y[d, i] = 1.0
        else:
            extra[d] = 1.0
    counts = np.array([len(L) for L, _, _ in days])
    present = np.arange(n)[None, :] < counts[:, None]
    kinds = np.array([k for _, _, k in days])
    grid = np.round(np.arange(0.0, 0.901, 0.02), 2)

    def per_day(log_t: float) -> np.ndarray:
        """Each day's Brier score at every ``eps`` of the grid: (days, grid)."""
        z = np.where(present, Lm / math.exp(log_t), -np.inf)
        z = z - z.max(axis=1, keepdims=True)
        e = np.where(present, np.exp(z), 0.0)
        q = e / e.sum(axis=1, keepdims=True)
        p = (1.0 - grid[None, :, None]) * q[:, None, :] \
            + grid[None, :, None] / counts[:, None, None]
        err = np.where(present[:, None, :], (p - Y[:, None, :]) ** 2, 0.0)
        return err.sum(axis=2) + extra[:, None]

    def loss(log_t: float) -> float:
        b = per_day(log_t)
        return float(sum(b[kinds == k].sum(axis=0).min() for k in set(kinds))) / len(days)

    res = minimize_scalar(loss, bounds=tuple(math.log(b) for b in t_bounds), method="bounded",
                          options={"xatol": 1e-3})
    b = per_day(float(res.x))
    wrong = np.array([i != int(np.argmax(L)) for L, i, _ in days])
    eps = {k: max(float(grid[int(np.argmin(b[kinds == k].sum(axis=0)))]),
                  (float(wrong[kinds == k].sum()) + 1.0) / (float((kinds == k).sum()) + 2.0))
           for k in set(kinds)}
    return float(math.exp(res.x)), eps
