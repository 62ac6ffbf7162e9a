"""Closed-loop design of experiments for the calibration (issue 15, the paper's future work).

On natural closed-loop days the seven multipliers are poorly identifiable
(:mod:`.identifiability`): the outlet-temperature loop holds ``T_dryer_out`` at its set point,
so the outputs barely move. An operator may move two knobs a little: the outlet-temperature set
point ``T_sp`` [K] (the PI then moves the flaps, hence ``T_air_in``) and the air flow ``m_air``
[kg/s]. This module proposes a schedule of such moves that maximises the information the
calibration's channels carry about the parameters.

Parametrisation
    The period of ``hours`` is cut into moves of ``move_minutes``; each move holds a level
    ``l`` in [-1, 1] per knob, mapped linearly onto the knob's band (``-1``: low end, ``+1``:
    high end). A pseudo-random binary sequence is the special case ``l = +-1``. From the
    operating point the set point follows the levels at no more than ``T_sp_rate`` [K/min]
    (and the air flow at no more than ``m_air_rate`` [kg/s per min]); the result is then
    clipped hard to the bands, so a schedule never leaves its limits whatever the levels.
Prediction
    A :class:`ClosedLoop` (supplied by the app layer: the plant's PI, flap drive and mixing
    around the calibrated model, disturbances held at the operating point) turns a schedule
    into the model's inputs and outputs per control step, and per model window.
Information
    The predicted period becomes a calibration :class:`~.dataset.Segment` (window means,
    lab samples every ``lab_minutes`` at the predicted ``moisture_out``), and
    :func:`~.identifiability.sensitivities` gives the rows the calibration's cost sees (the
    inlet-moisture nuisance profiled out). The criteria:

    * ``"D"``: ``ln det`` of the weighted FIM (the Table 3 form of :func:`weighted_fim`);
    * ``"A"``: minus the trace of the posterior covariance ``(F + P0)^-1`` (ln theta) over the
      parameters the user names (all seven by default), ``F`` the statistical FIM with the
      channels' noise, ``P0`` the prior precision.
Limits
    Hard clipping of the schedule, and the predicted outlet-moisture excursion from the
    operating point's value: a candidate beyond ``moisture_excursion`` [kg/kg] is repaired by
    shrinking its levels towards the operating point (factors :data:`SHRINK`), and rejected
    when even the smallest shrink exceeds the bound.
Search
    Seeded random multi-level sequences (levels :data:`LEVELS`; a PRBS uses only the ends),
    then coordinate moves (one level of one knob set to another of :data:`LEVELS`, in a seeded
    order, kept when the criterion improves) within an evaluation budget. The search is
    deterministic for a seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from softsensor.calibration.dataset import Segment
from softsensor.calibration.identifiability import (
    condition_number,
    noise_from_evaluation,
    sensitivities,
    statistical_fim,
    weighted_fim,
)
from softsensor.calibration.objective import ObjectiveSpec
from softsensor.errors import ConfigError, SolverError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES

#: Criteria :func:`criterion` knows.
CRITERIA: tuple[str, ...] = ("D", "A")
#: Level factors tried, in order, to bring a candidate's moisture excursion within its bound.
SHRINK: tuple[float, ...] = (1.0, 0.7, 0.5, 0.35, 0.25, 0.15, 0.1)
#: Levels the search tries: the band's ends, its middle and half-way (a temperature move and
#: an air-flow move of opposite effect on the outlet moisture may only fit the bound together
#: at part amplitude).
LEVELS: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
#: Ridge, relative to the mean eigenvalue, that keeps ln det finite for a rank-deficient FIM.
RIDGE = 1e-12
NS = 1_000_000_000


@dataclass(frozen=True)
class DesignLimits:
    """What the operator allows during the designed period (SI, times as named).

    ``T_sp_band`` [K] and ``m_air_band`` [kg/s] are (low, high); ``T_sp_rate`` [K/min] and
    ``m_air_rate`` [kg/s per min] bound the moves; ``moisture_excursion`` [kg/kg] bounds the
    predicted outlet moisture's distance from the operating point's; ``hours`` [h] is the
    period, ``move_minutes`` [min] the shortest hold of a level, ``lab_minutes`` [min] the lab
    sampling interval asked for during the period.
    """

    T_sp_band: tuple[float, float]
    m_air_band: tuple[float, float]
    T_sp_rate: float = 0.5
    m_air_rate: float = 2.0
    moisture_excursion: float = 0.01
    hours: float = 6.0
    move_minutes: float = 30.0
    lab_minutes: float = 30.0

    def check(self, T_sp0: float | None = None, m_air0: float | None = None) -> str | None:
        """One line naming the first bad limit (None when all are good); with the operating
        point, also that it lies inside the bands (the schedule starts there)."""
        for name, (lo, hi) in (("T_sp band", self.T_sp_band), ("m_air band", self.m_air_band)):
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
                return f"{name} must be 0 < low < high, got [{lo:g}, {hi:g}]"
        for name, v in (("T_sp rate", self.T_sp_rate), ("m_air rate", self.m_air_rate),
                        ("moisture excursion", self.moisture_excursion),
                        ("hours", self.hours), ("move minutes", self.move_minutes),
                        ("lab minutes", self.lab_minutes)):
            if not (math.isfinite(v) and v > 0):
                return f"{name} must be > 0, got {v:g}"
        if self.move_minutes > 60 * self.hours:
            return f"move minutes ({self.move_minutes:g}) exceed the period ({self.hours:g} h)"
        for name, v, (lo, hi) in (("T_sp", T_sp0, self.T_sp_band),
                                  ("m_air", m_air0, self.m_air_band)):
            if v is not None and not lo <= v <= hi:
                return (f"the operating point's {name} {v:g} lies outside its band "
                        f"[{lo:g}, {hi:g}]")
        return None

    @property
    def n_moves(self) -> int:
        """Number of levels per knob."""
        return max(1, int(math.ceil(60.0 * self.hours / self.move_minutes - 1e-9)))


@dataclass(frozen=True)
class Schedule:
    """Knob trajectories on the control grid: ``t`` [s from the start], ``T_sp`` [K],
    ``m_air`` [kg/s]; ``levels`` (2, n_moves) the normalised levels they came from."""

    t: np.ndarray
    T_sp: np.ndarray
    m_air: np.ndarray
    levels: np.ndarray


def _follow(target: np.ndarray, start: float, rate: float, dt: float) -> np.ndarray:
    """``target`` followed from ``start`` at no more than ``rate`` per second."""
    out = np.empty_like(target)
    x = start
    step = rate * dt
    for k, v in enumerate(target):
        x += min(max(v - x, -step), step)
        out[k] = x
    return out


def schedule_from_levels(levels: np.ndarray, limits: DesignLimits, T_sp0: float,
                         m_air0: float, dt: float) -> Schedule:
    """The schedule of ``levels`` (2, n_moves) in [-1, 1] (module docstring), from the
    operating point (``T_sp0`` [K], ``m_air0`` [kg/s]) at control steps of ``dt`` [s]."""
    lv = np.clip(np.asarray(levels, float).reshape(2, limits.n_moves), -1.0, 1.0)
    n = int(round(limits.hours * 3600.0 / dt)) + 1
    t = np.arange(n) * dt
    move = np.minimum((t // (60.0 * limits.move_minutes)).astype(int), limits.n_moves - 1)
    knobs = []
    for j, (band, rate, x0) in enumerate(((limits.T_sp_band, limits.T_sp_rate, T_sp0),
                                          (limits.m_air_band, limits.m_air_rate, m_air0))):
        lo, hi = band
        target = lo + 0.5 * (lv[j, move] + 1.0) * (hi - lo)
        # rate limit first, then hard clipping: clipping can only slow a move, never break
        # the rate, and the bands hold whatever the levels
        knobs.append(np.clip(_follow(target, x0, rate / 60.0, dt), lo, hi))
    return Schedule(t=t, T_sp=knobs[0], m_air=knobs[1], levels=lv)


def constant_levels(limits: DesignLimits, T_sp0: float, m_air0: float) -> np.ndarray:
    """The levels that hold the operating point (the natural, undisturbed schedule)."""
    out = []
    for (lo, hi), x0 in ((limits.T_sp_band, T_sp0), (limits.m_air_band, m_air0)):
        out.append(np.full(limits.n_moves, 2.0 * (x0 - lo) / (hi - lo) - 1.0))
    return np.array(out)


@dataclass(frozen=True)
class Prediction:
    """A closed-loop prediction of a schedule.

    ``t`` [s], per control step: ``U`` (n, 8) the model inputs (``INPUT_NAMES`` order, the
    loop's ``T_air_in`` among them) and ``Y`` (n, 3) the outputs (``T_dryer_out``,
    ``T_cyclone_out`` [K], ``moisture_out`` [kg/kg]); ``flap`` (n,) the flap command [%].
    """

    t: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    flap: np.ndarray


class ClosedLoop(Protocol):
    """The plant's outlet-temperature loop around the model (the app layer supplies it)."""

    dt: float
    T_sp0: float
    m_air0: float

    def run(self, schedule: Schedule, theta: np.ndarray) -> Prediction:
        """Predict ``schedule`` with parameters ``theta`` (7,); raises SolverError."""
        ...


def window_means(pred: Prediction, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Means of inputs and outputs over consecutive ``window`` [s] spans ``(start, end]``."""
    dt = float(pred.t[1] - pred.t[0])
    per = max(1, int(round(window / dt)))
    K = (len(pred.t) - 1) // per
    U = pred.U[1:1 + K * per].reshape(K, per, -1).mean(axis=1)
    Y = pred.Y[1:1 + K * per].reshape(K, per, -1).mean(axis=1)
    return U, Y


def prediction_segment(pred: Prediction, window: float, lab_minutes: float, start_ns: int,
                       source: str = "design") -> Segment:
    """A predicted period as the calibration sees it: window means [K, kg/s, ...] and lab
    samples of the predicted ``moisture_out`` [kg/kg] every ``lab_minutes`` (the first one
    ``lab_minutes`` after the start)."""
    U, Y = window_means(pred, window)
    Y = Y.copy()
    Y[:, 2] = np.nan  # moisture is measured by the lab only
    end = len(U) * window
    t_lab = np.arange(60.0 * lab_minutes, end + 1e-9, 60.0 * lab_minutes)
    lab_value = np.interp(t_lab, pred.t, pred.Y[:, 2])
    lab_ns = start_ns + np.round(t_lab * NS).astype(np.int64)
    return Segment(source=source, start_ns=int(start_ns), window=float(window), U=U, Y=Y,
                   lab_time_ns=lab_ns, lab_value=lab_value,
                   lab_id=tuple(f"D{i:03d}" for i in range(len(t_lab))))


@dataclass(frozen=True)
class Information:
    """What a period tells about the parameters (ln theta).

    ``fim`` the weighted FIM (Table 3 form), ``logdet`` its ln det (ridge :data:`RIDGE`),
    ``condition`` its condition number; ``covariance`` the posterior ``(F + P0)^-1`` with
    ``F`` the statistical FIM; ``se`` its standard errors (0.05: about 5 %);
    ``logdet_posterior`` ln det of ``F + P0`` (finite even when ``fim`` is singular).
    """

    fim: np.ndarray
    logdet: float
    condition: float
    covariance: np.ndarray
    se: np.ndarray
    logdet_posterior: float

    def as_dict(self) -> dict[str, object]:
        return {"logdet_weighted_fim": self.logdet, "condition_number": self.condition,
                "logdet_posterior_precision": self.logdet_posterior,
                "relative_se": dict(zip(PARAMETER_NAMES, map(float, self.se), strict=True))}


def information(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                spec: ObjectiveSpec, noise: np.ndarray | None, prior_sd: np.ndarray
                ) -> Information:
    """The information of ``segments`` at ``theta`` (7,): ``noise`` [K, K, kg/kg] per channel
    for the statistical FIM (None: what the fit at ``theta`` leaves, as ``identify`` takes
    it), ``prior_sd`` (7,) the prior sd of ln theta."""
    sens, ev = sensitivities(model, segments, theta, spec)
    if noise is None:
        noise = noise_from_evaluation(ev)
    F = weighted_fim(sens, spec.weights)
    cond, lam, _ = condition_number(F)
    ridge = RIDGE * max(float(np.mean(np.abs(lam))), 1e-300)
    logdet = float(np.sum(np.log(np.maximum(lam, 0.0) + ridge)))
    P = statistical_fim(sens, np.asarray(noise, float)) + np.diag(1.0 / np.asarray(prior_sd) ** 2)
    C = np.linalg.inv(P)
    C = 0.5 * (C + C.T)
    return Information(fim=F, logdet=logdet, condition=cond, covariance=C,
                       se=np.sqrt(np.diag(C)), logdet_posterior=float(np.linalg.slogdet(P)[1]))


def criterion(info: Information, kind: str, names: Sequence[str] = ()) -> float:
    """The design criterion, larger is better: ``"D"`` ln det of the weighted FIM, ``"A"``
    minus the posterior variance of ln theta summed over ``names`` (all when empty)."""
    if kind == "D":
        return info.logdet
    if kind == "A":
        idx = [PARAMETER_NAMES.index(n) for n in names] if names else range(len(PARAMETER_NAMES))
        return -float(sum(info.covariance[i, i] for i in idx))
    raise ConfigError(f"unknown design criterion {kind!r} (known: {', '.join(CRITERIA)})")


@dataclass(frozen=True)
class DesignProblem:
    """Everything a candidate is scored with (see the module docstring)."""

    model: DryerModel
    loop: ClosedLoop
    theta: np.ndarray
    spec: ObjectiveSpec
    limits: DesignLimits
    noise: np.ndarray
    prior_sd: np.ndarray
    window: float
    start_ns: int
    kind: str = "D"
    names: tuple[str, ...] = ()

    def check(self) -> None:
        """Raise :class:`ConfigError` for bad limits, criterion or parameter names."""
        msg = self.limits.check(self.loop.T_sp0, self.loop.m_air0)
        if msg:
            raise ConfigError(msg)
        if self.kind not in CRITERIA:
            raise ConfigError(f"unknown design criterion {self.kind!r} "
                              f"(known: {', '.join(CRITERIA)})")
        bad = [n for n in self.names if n not in PARAMETER_NAMES]
        if bad:
            raise ConfigError(f"unknown parameter(s) {', '.join(bad)} "
                              f"(known: {', '.join(PARAMETER_NAMES)})")


@dataclass(frozen=True)
class Candidate:
    """A scored schedule: ``score`` the criterion (``-inf`` when rejected), ``excursion``
    [kg/kg] the largest predicted ``|moisture_out - baseline|``, ``shrink`` the level factor
    applied to meet the bound."""

    schedule: Schedule
    prediction: Prediction
    segment: Segment
    info: Information | None
    score: float
    excursion: float
    shrink: float
    feasible: bool


def _score_schedule(problem: DesignProblem, sched: Schedule, baseline: float,
                    shrink: float, pred: Prediction | None = None) -> Candidate:
    """Predict (unless ``pred`` is that prediction) and score one schedule (rejected when
    the excursion exceeds its bound)."""
    if pred is None:
        pred = problem.loop.run(sched, problem.theta)
    exc = float(np.max(np.abs(pred.Y[:, 2] - baseline)))
    seg = prediction_segment(pred, problem.window, problem.limits.lab_minutes, problem.start_ns)
    if exc > problem.limits.moisture_excursion:
        return Candidate(sched, pred, seg, None, -math.inf, exc, shrink, False)
    info = information(problem.model, [seg], problem.theta, problem.spec, problem.noise,
                       problem.prior_sd)
    return Candidate(sched, pred, seg, info, criterion(info, problem.kind, problem.names),
                     exc, shrink, True)


def evaluate_levels(problem: DesignProblem, levels: np.ndarray, baseline: float) -> Candidate:
    """Score ``levels`` (2, n_moves), shrinking them towards the operating point
    (:data:`SHRINK`) until the predicted moisture excursion from ``baseline`` [kg/kg] is
    within its bound; the last, still infeasible, try when none is."""
    loop, lim = problem.loop, problem.limits
    home = constant_levels(lim, loop.T_sp0, loop.m_air0)
    cand = None
    for f in SHRINK:
        lv = home + f * (np.clip(levels, -1, 1) - home)
        sched = schedule_from_levels(lv, lim, loop.T_sp0, loop.m_air0, loop.dt)
        try:
            cand = _score_schedule(problem, sched, baseline, f)
        except SolverError:
            continue  # a schedule the model cannot follow is no design; shrink it
        if cand.feasible:
            return cand
    if cand is None:
        raise SolverError("the model fails on every shrink of the candidate schedule")
    return cand


@dataclass
class DesignResult:
    """The search's outcome: ``best`` and the ``natural`` (constant) schedule scored alike,
    ``history`` the criterion of every evaluated candidate in order."""

    best: Candidate
    natural: Candidate
    baseline: float
    history: list[float] = field(default_factory=list)


def natural_candidate(problem: DesignProblem) -> tuple[Candidate, float]:
    """The constant schedule at the operating point and its outlet moisture [kg/kg] (the
    excursion's reference: the mean of the prediction's second half, past the start-up)."""
    loop = problem.loop
    lv = constant_levels(problem.limits, loop.T_sp0, loop.m_air0)
    sched = schedule_from_levels(lv, problem.limits, loop.T_sp0, loop.m_air0, loop.dt)
    pred = loop.run(sched, problem.theta)
    baseline = float(np.mean(pred.Y[len(pred.Y) // 2:, 2]))
    return _score_schedule(problem, sched, baseline, 1.0, pred), baseline


def optimise(problem: DesignProblem, *, seed: int = 0, n_random: int = 6, budget: int = 30,
             say: Callable[[str], None] | None = None) -> DesignResult:
    """Search the levels (module docstring): ``n_random`` random candidates, then coordinate
    moves until ``budget`` evaluations are spent. Raises :class:`ConfigError` for bad limits
    and :class:`SolverError` when no candidate meets the moisture bound."""
    problem.check()
    natural, baseline = natural_candidate(problem)
    rng = np.random.default_rng(seed)
    n = problem.limits.n_moves
    result = DesignResult(best=natural, natural=natural, baseline=baseline)
    best_levels = constant_levels(problem.limits, problem.loop.T_sp0, problem.loop.m_air0)

    def consider(levels: np.ndarray) -> bool:
        cand = evaluate_levels(problem, levels, baseline)
        result.history.append(cand.score)
        if cand.feasible and cand.score > result.best.score:
            result.best = cand
            return True
        return False

    for _ in range(n_random):
        lv = rng.choice(LEVELS, size=(2, n))
        if consider(lv):
            best_levels = lv
    moves = [(j, i, v) for i in range(n) for j in range(2) for v in LEVELS]
    for j, i, v in (moves[k] for k in rng.permutation(len(moves))):
        if len(result.history) >= budget:
            break
        if best_levels[j, i] == v:
            continue
        lv = best_levels.copy()
        lv[j, i] = v
        if consider(lv):
            best_levels = lv
            if say:
                say(f"evaluation {len(result.history)}: criterion {result.best.score:.4g}")
    if result.best is natural:  # every candidate was rejected
        raise SolverError(f"no schedule within the limits keeps the predicted outlet-moisture "
                          f"excursion within {problem.limits.moisture_excursion:g} kg/kg")
    return result


def gain(design: Information, natural: Information) -> dict[str, object]:
    """The information gain of a design over natural operation: ln det ratios (weighted FIM
    and posterior precision), condition numbers, standard errors of ln theta."""
    return {
        "logdet_ratio_weighted_fim": design.logdet - natural.logdet,
        "logdet_ratio_posterior_precision": design.logdet_posterior - natural.logdet_posterior,
        "condition_number": {"design": design.condition, "natural": natural.condition},
        "relative_se": {n: {"design": float(design.se[i]), "natural": float(natural.se[i])}
                        for i, n in enumerate(PARAMETER_NAMES)},
    }


@dataclass(frozen=True)
class Round:
    """One round of sequential design: the parameters it was designed at, the estimate
    after its period was recorded and re-calibrated, and the standard errors of ln theta on
    all periods recorded so far at that estimate."""

    index: int
    theta_design: np.ndarray
    theta: np.ndarray
    criterion: float
    se: np.ndarray
    condition: float


def sequential(design_at: Callable[[np.ndarray], DesignResult],
               record: Callable[[Schedule, int], Segment],
               recalibrate: Callable[[list[Segment], np.ndarray], np.ndarray],
               assess: Callable[[list[Segment], np.ndarray], Information],
               theta0: np.ndarray, rounds: int) -> list[Round]:
    """Sequential design: per round, design at the current estimate, record the schedule
    (``record(schedule, round)`` gives the recorded period as a segment), re-calibrate on
    every period so far, assess the standard errors there."""
    theta = np.asarray(theta0, float)
    recorded: list[Segment] = []
    out = []
    for r in range(int(rounds)):
        res = design_at(theta)
        recorded.append(record(res.best.schedule, r))
        new = np.asarray(recalibrate(list(recorded), theta), float)
        info = assess(list(recorded), new)
        out.append(Round(index=r, theta_design=theta, theta=new, criterion=res.best.score,
                         se=info.se, condition=info.condition))
        theta = new
    return out


__all__ = [
    "CRITERIA",
    "Candidate",
    "ClosedLoop",
    "DesignLimits",
    "DesignProblem",
    "DesignResult",
    "Information",
    "Prediction",
    "Round",
    "Schedule",
    "constant_levels",
    "criterion",
    "evaluate_levels",
    "gain",
    "information",
    "natural_candidate",
    "optimise",
    "prediction_segment",
    "schedule_from_levels",
    "sequential",
    "window_means",
]
