"""Diagnose a recorded day: residuals, evidence, fitted extensions, held-out verdict.

:func:`diagnose` runs the whole of issue 6 on one day with an already calibrated config:

1. cut the day into model windows (:mod:`.day_windows`) and split it into a fit part and a
   held-out part (:func:`~.problem.choose_split`, 60 % by default, moved so that both parts
   hold lab results);
2. run the calibrated model on the day (the baseline) and compute the residual statistics of
   every channel (:mod:`.residuals`);
3. fit every plausible extension of :data:`~.extensions.EXTENSIONS` on the fit part and,
   separately, on the held-out part, and score it on the data each fit did not see
   (:mod:`.verdict`); only the costly inlet-moisture filter is skipped when the residuals
   rule it out (:func:`implausible`);
4. name the cause and write the evidence (:mod:`.evidence`);
5. fit every cause's shape on the baseline's residuals against the normal (:mod:`.shapes`,
   each with its exact marginal evidence) and give every cause its probability
   (:mod:`.posterior`; a cause takes the larger of its extension's and its shape's
   evidence), with every cause's signature on this day and the size the normal can see of it
   (:mod:`.detectability`), and say where the two most probable causes cannot be told apart
   on this day's data and what data would;
6. when a shape has the most evidence of all, name its cause without a winning extension
   (:func:`after_shapes`), unless the verdict's eligible extension is of that cause already.

The result, :class:`Diagnosis`, turns into the REPORT.json of CONTRACT section 5
(:meth:`Diagnosis.to_json`) and feeds the report page
(:mod:`softsensor.presentation.diagnosis_report`). Nothing here reads the
ground truth a simulated day may carry.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.diagnosis.day_windows import DayLike, DayWindows, day_windows
from softsensor.diagnosis.detectability import Signature, signatures
from softsensor.diagnosis.evidence import ResidualSummary, evidence_text, shape_text
from softsensor.diagnosis.extensions import EXTENSIONS, Extension, Fitted, LabTimeShift
from softsensor.diagnosis.instrument import offset_contradiction
from softsensor.diagnosis.plant_normal import PlantNormal
from softsensor.diagnosis.posterior import Candidate, cannot_tell, posterior
from softsensor.diagnosis.problem import DEFAULT_FIT_FRACTION, Prediction, Problem, choose_split
from softsensor.diagnosis.residuals import LAB_SHIFTS_MIN, channel_stats, lab_stats
from softsensor.diagnosis.settings import DiagnosisSettings, diagnosis_settings
from softsensor.diagnosis.shapes import SHAPES, Shape, ShapeFit
from softsensor.diagnosis.verdict import (
    Score,
    Verdict,
    cross_fitted,
    score,
    structure_margins,
    structured,
    verdict,
)
from softsensor.estimation.settings import estimator_settings
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS, OUTPUT_NAMES

log = logging.getLogger(__name__)

_M_IN = INPUT_NAMES.index("moisture_in")

#: How the reported RMSEs, costs and gain are held out (REPORT.json ``held_out.method``).
HELD_OUT_METHOD = (
    "two-fold cross-fitting: the day is split in two at split_time_ns; every extension is "
    "fitted once on each part and each part is predicted by the fit on the other, so every "
    "window and lab result is scored by an extension that was not fitted on it; split_* "
    "numbers are those of the held-out part of the first fold alone")


@dataclass
class Diagnosis:
    """Everything one diagnosis produced."""

    problem: Problem
    summary: ResidualSummary
    fitted: dict[str, Fitted]
    scores: dict[str, Score]
    other_fold: dict[str, Fitted]
    verdict: Verdict
    sigma: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    source: str = "day"
    skipped: dict[str, str] = field(default_factory=dict)
    signatures: dict[str, Signature] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)
    undecided: dict[str, Any] | None = None
    shapes: dict[str, ShapeFit] = field(default_factory=dict)
    #: How the probabilities were judged (:func:`normal_note`): against the plant's own
    #: history days, and whether there were enough of them.
    normal: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> ShapeFit | None:
        """The shape that named the cause (None: an extension, or the baseline, did; an
        eligible extension that won the verdict keeps it even where its cause's shape has
        the larger evidence, :func:`after_shapes`)."""
        c = self.candidates[0] if self.candidates else None
        if c is None or c.source != "shape" or self.verdict.winner is not None:
            return None
        return self.shapes.get(c.cause)

    @property
    def cause(self) -> str:
        return self.verdict.cause

    @property
    def winner(self) -> Fitted | None:
        w = self.verdict.winner
        return None if w is None else self.fitted[w.cause]

    def cross_fitted(self, cause: str) -> Prediction:
        """The extension of ``cause`` as scored: each part of the day predicted by the fold
        fitted on the other part (:func:`~.verdict.cross_fitted`)."""
        return cross_fitted(self.problem, self.fitted[cause].prediction,
                            self.other_fold[cause].prediction)

    def _ranking_json(self) -> list[dict[str, Any]]:
        """REPORT.json's ``ranking``: every cause with its weight and evidence, the fitted
        ones with their scores and parameters on both folds, the skipped ones with why."""
        v = self.verdict
        ranking: list[dict[str, Any]] = []
        for cause, weight, sc in v.ranking:
            fitted = self.fitted.get(cause) if sc is not None else None
            entry: dict[str, Any] = {
                "cause": cause, "score": round(float(weight), 6),
                "evidence": evidence_text(cause, self.summary, fitted, sc, v.structure)}
            if sc is not None and fitted is not None:
                entry.update({
                    "eligible": bool(sc.eligible), "gain": _num(sc.gain),
                    "penalised_loglik_gain": _num(sc.penalised),
                    "loglik_gain": {k: _num(x) for k, x in sc.loglik.items()},
                    "split_gain": _num(sc.split_gain),
                    "params": {k: _num(x) for k, x in fitted.params.items()},
                    "params_other_fold": {k: _num(x) for k, x in
                                          self.other_fold[cause].params.items()},
                    "channel": fitted.channel, "contradicted": sc.contradicted})
            if cause in self.skipped:
                entry.update({"eligible": False, "evidence": entry["evidence"]
                              + f". Not fitted: {self.skipped[cause]}"})
            fit = self.shapes.get(cause)
            if fit is not None:
                entry["evidence"] += f". Shape on the residuals: {shape_text(fit)}"
                entry["shape"] = fit.to_json()
                if fit is self.shape:
                    entry.update({"params": dict(fit.params), "channel": fit.channel})
            ranking.append(entry)
        ranked = {r[0] for r in v.ranking}
        for cause, reason in self.skipped.items():
            if cause in ranked:  # named by a shape: every candidate ranked already
                continue
            ranking.append({"cause": cause, "score": 0.0, "eligible": False,
                            "evidence": evidence_text(cause, self.summary, None, None)
                            + f". Not fitted: {reason}"})
        return ranking

    def _channel(self) -> str | None:
        """The thermometer of a named ``sensor_bias`` (CONTRACT section 5), else None."""
        if self.cause != "sensor_bias":
            return None
        win = self.verdict.winner
        if win is not None:
            return win.channel
        return None if self.shape is None else self.shape.channel

    def to_json(self) -> dict[str, Any]:
        """REPORT.json (CONTRACT section 5) plus the project's extra fields."""
        v = self.verdict
        win = v.winner
        any_score = next(iter(self.scores.values()))
        base = any_score.baseline
        ext = win.extended if win is not None else base
        p = self.problem
        ranking = self._ranking_json()
        split = p.split
        out: dict[str, Any] = {
            "cause": v.cause,
            "ranking": ranking,
            "channel": self._channel(),
            "baseline_rmse": {k: _num(x) for k, x in base.rmse.items()},
            "extended_rmse": {k: _num(x) for k, x in ext.rmse.items()},
            "baseline_cost": _num(base.cost),
            "extended_cost": _num(ext.cost),
            "gain": _num(win.gain if win is not None else 0.0),
            "day": self.source,
            "extension": None if win is None else {
                "cause": win.cause, "params": {k: _num(x) for k, x in
                                               self.fitted[win.cause].params.items()},
                "params_other_fold": {k: _num(x) for k, x in
                                      self.other_fold[win.cause].params.items()},
                "description": self.fitted[win.cause].description},
            "held_out": {
                "method": HELD_OUT_METHOD,
                "fit_windows": split.k_fit, "held_out_windows": p.windows.n_windows - split.k_fit,
                "fit_labs": int(split.lab_fit.sum()), "held_out_labs": int(split.lab_held.sum()),
                "split_time_ns": split.split_ns, "note": split.note,
                "samples": dict(base.n),
                "split_baseline_cost": _num(any_score.split_baseline.cost),
                "split_extended_cost": _num(win.split_extended.cost if win is not None
                                            else any_score.split_baseline.cost),
                "split_gain": _num(win.split_gain if win is not None else 0.0)},
            "noise_levels": {k: _num(x) for k, x in zip(OUTPUT_NAMES, self.sigma, strict=True)},
            "structure": v.structure,
            "probabilities": [c.to_json() for c in self.candidates],
            "plant_normal": self.normal,
            "shape": None if self.shape is None else self.shape.to_json(),
            "shapes": {c: f.to_json() for c, f in self.shapes.items()},
            "cannot_tell": [] if self.undecided is None else self.undecided["causes"],
            "cannot_tell_collinearity": None if self.undecided is None
            else self.undecided["collinearity"],
            "cannot_tell_separate": None if self.undecided is None
            else self.undecided["separate"],
            "detectability": {c: sg.to_json() for c, sg in self.signatures.items()},
            "parameters": {k: _num(x) for k, x in zip(PARAMETER_NAMES, p.theta, strict=True)},
            "timings_s": {k: round(x, 2) for k, x in self.timings.items()},
        }
        return out


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _signature(model: DryerModel, windows: DayWindows, theta: np.ndarray) -> np.ndarray:
    """Steady output change per +0.1 kg/kg of inlet moisture at the day's mean inputs."""
    u = windows.U.mean(axis=0)
    U = np.stack([u, u])
    U[1, _M_IN] += 0.1
    _, y = model.steady_state(U, theta)
    return y[1] - y[0]


def summarise(problem: Problem) -> ResidualSummary:
    """Baseline residual statistics of the whole day (:mod:`.residuals`)."""
    w = problem.windows
    r = problem.residuals(problem.baseline)
    chans = [channel_stats(name, r.T[:, c], w, problem.sigma[c])
             for c, name in enumerate(KELVIN_CHANNELS)]
    _, shifted = LabTimeShift.lab_chi2(problem, LAB_SHIFTS_MIN)
    lab = lab_stats(r.lab, w, problem.baseline.Y[:, 2], shifted)
    ok = np.isfinite(r.T).all(axis=1)
    a, b = r.T[ok, 0], r.T[ok, 1]
    corr = float(np.corrcoef(a, b)[0, 1]) if ok.sum() > 3 and a.std() > 0 and b.std() > 0 \
        else 0.0
    da = a - a.mean()
    ratio = float(da @ (b - b.mean()) / (da @ da)) if float(da @ da) > 0 else 0.0
    sig = _signature(problem.model, w, problem.theta)
    return ResidualSummary(chans, lab, problem.sigma, sig, ratio, corr)


#: The inlet-moisture filter is fitted only when both temperature residuals exceed this many
#: noise levels ...
INLET_MIN_STRUCTURE = 2.0
#: ... and move together at least this closely.
INLET_MIN_CORRELATION = 0.8


def implausible(cause: str, summary: ResidualSummary) -> str | None:
    """Why the residuals rule ``cause`` out before any fit (None: fit it).

    Only the inlet-moisture filter is gated, being the one costly fit (a UKF run per tried
    intensity, about two thirds of a diagnosis). Under closed loop an inlet-moisture change
    shows in both outlet temperatures at once: with measured ``T_air_in`` the model misses
    the evaporation load in both (on virtual-plant days with the effect, both residuals exceed
    10 noise levels with correlation 0.99). Residuals at noise level, or on one channel only,
    leave nothing for the filter to track.
    """
    if cause != "inlet_moisture":
        return None
    d, c = summary.channels
    ratios = (d.structure_ratio, c.structure_ratio)
    if min(ratios) < INLET_MIN_STRUCTURE or summary.corr_dry_cyc < INLET_MIN_CORRELATION:
        return (f"an inlet-moisture change moves both outlet temperatures together; here their "
                f"residuals are {ratios[0]:.1f} and {ratios[1]:.1f} noise levels (needed: "
                f"{INLET_MIN_STRUCTURE:g}) with correlation {summary.corr_dry_cyc:+.2f} "
                f"(needed: {INLET_MIN_CORRELATION:g})")
    return None


#: The labs' whitened log-likelihood gain under the inlet-moisture extension below which
#: they do not follow the outlet moisture its inlet estimate implies. [nats] Two: a
#: likelihood ratio of about 7 in favour of the estimate's outlet moisture at the lab times.
LABS_FOLLOW = 2.0


def labs_refute_inlet(sc: Score) -> str | None:
    """Why an inlet-moisture verdict is refused (None: the labs follow it). The filter reads
    the inlet moisture from the outlet temperatures alone; an unmeasured change of air flow
    or heat input moves them the same way, and only the labs tell the two apart: the inlet
    estimate implies an outlet moisture at every lab time, and unless the labs follow it
    (their log-likelihood gains at least :data:`LABS_FOLLOW` on the cross-fitted
    prediction) the day is not named ``inlet_moisture`` (issue 48: a day whose air flow
    oscillated behind a flat meter was named ``inlet_moisture`` at 0.917 while the labs never
    followed an estimate running from 0.98 to 1.17 kg/kg)."""
    gain = sc.loglik.get("moisture_out", math.nan)
    if sc.baseline.n.get("moisture_out", 0) and gain >= LABS_FOLLOW:
        return None
    return (f"the labs do not follow the outlet moisture this inlet estimate implies (their "
            f"log-likelihood {gain:+.1f}, needed {LABS_FOLLOW:g}): an unmeasured change of "
            f"air flow or heat input moves the outlet temperatures the same way")


def _fit_extensions(problem: Problem, summary: ResidualSummary,
                    extensions: tuple[Extension, ...], say: Callable[[str], None],
                    timings: dict[str, float]
                    ) -> tuple[dict[str, Fitted], dict[str, Fitted], dict[str, Score],
                               dict[str, str]]:
    """Fit every extension the residuals do not rule out (:func:`implausible`) on both folds
    and score it; ``(fitted, other_fold, scores, skipped)`` by cause (``skipped``: why not
    fitted), each fit's seconds in ``timings[cause]``."""
    fitted: dict[str, Fitted] = {}
    other_fold: dict[str, Fitted] = {}
    scores: dict[str, Score] = {}
    skipped: dict[str, str] = {}
    for i, ext in enumerate(extensions, 1):
        reason = implausible(ext.cause, summary)
        if reason is not None:
            skipped[ext.cause] = reason
            continue
        say(f"extension {i} of {len(extensions)}: {ext.cause}")
        t1 = time.perf_counter()
        f, b = ext.fit_both(problem)
        fitted[f.cause], other_fold[f.cause] = f, b
        scores[f.cause] = score(problem, f, b)
        if f.cause == "sensor_bias" and f.channel is not None:
            scores[f.cause] = dataclasses.replace(
                scores[f.cause], contradicted=offset_contradiction(problem, f.channel))
        elif f.cause == "inlet_moisture":
            scores[f.cause] = dataclasses.replace(
                scores[f.cause], contradicted=labs_refute_inlet(scores[f.cause]))
        timings[f.cause] = time.perf_counter() - t1
        log.debug("diagnose %s: %s; penalised gain %.1f", f.cause, f.description,
                  scores[f.cause].penalised)
    return fitted, other_fold, scores, skipped


def diagnose(config: PlantConfig, day: DayLike, *,
             fit_fraction: float = DEFAULT_FIT_FRACTION,
             extensions: tuple[Extension, ...] = EXTENSIONS, source: str = "day",
             shapes: tuple[Shape, ...] = SHAPES,
             model: DryerModel | None = None,
             normal: PlantNormal | None = None,
             progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Diagnose ``day`` with the calibrated ``config`` (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant config carrying the calibrated parameter values and, from the calibration's
        PARAMS.toml, the ``[discrepancy]`` the calibration left on held-out data: the size of
        the calibration-error alternative every extension is tested against
        (:mod:`.calibration_error`; the estimator's defaults without it).
    day : RecordedDay or SimulatedDay
        The day to diagnose (``scans`` and ``labs``; ground truth is never read).
    fit_fraction : float
        Share of the windows the extensions are fitted on.
    shapes : tuple of Shape
        The causes' shapes on the residuals (:mod:`.shapes`), ranked with the extensions.
    normal : PlantNormal, optional
        The plant's own history days as judged against a normal that did not see them
        (:mod:`.plant_normal`): the probabilities are judged against it, with the prior of
        the config's ``[diagnosis]`` (:mod:`softsensor.diagnosis.settings`). Without it,
        or with fewer history days than ``[diagnosis]`` ``min_history_days``, the verdict
        says there is too little history and no cause gets more than
        ``cap_without_history``.
    progress : callable, optional
        Called with a short phase description as each phase starts (the verb prints them:
        a diagnosis takes minutes).
    """
    say = progress or (lambda _phase: None)
    t0 = time.perf_counter()
    say("baseline: the calibrated model over the day")
    timings: dict[str, float] = {}
    model = model if model is not None else DryerModel(config)
    windows = day_windows(day, config, source)
    split = choose_split(windows, fit_fraction)
    lab_std = estimator_settings(config).lab_std
    problem = Problem(config, model, windows, split, model.theta0, lab_std)
    sigma = problem.sigma
    summary = summarise(problem)
    timings["baseline"] = time.perf_counter() - t0
    fitted, other_fold, scores, skipped = _fit_extensions(problem, summary, extensions, say,
                                                          timings)
    struct = structured(problem)
    v = verdict(list(scores.values()), struct)
    say("probabilities and what this day can show of every cause")
    t1 = time.perf_counter()
    sigs = signatures(problem, extensions, fitted)
    margin = max((m for m, _, _ in structure_margins(problem).values()), default=-math.inf)
    say("every cause's shape on the residuals")
    fits = {sh.cause: sh.fit(problem) for sh in shapes}
    settings = diagnosis_settings(config)
    cands = posterior(v, scores.values(), skipped, margin, shapes=fits.values(),
                      normal=normal, settings=settings)
    v = after_shapes(v, cands, scores, skipped)
    timings["probabilities"] = time.perf_counter() - t1
    timings["total"] = time.perf_counter() - t0
    judged = normal is not None and normal.n_days >= 2
    return Diagnosis(problem, summary, fitted, scores, other_fold, v, sigma, timings, source,
                     skipped, sigs, cands, cannot_tell(cands, sigs, by_probability=judged),
                     fits, normal_note(normal, settings))


def normal_note(normal: PlantNormal | None, settings: DiagnosisSettings) -> dict[str, Any]:
    """REPORT.json's ``plant_normal``: how many history days the probabilities were judged
    against, whether that is enough to know the plant's normal (``enough``), the prior base
    rate and the cap that held without enough of them."""
    n = 0 if normal is None else normal.n_days
    enough = n >= settings.min_history_days
    return {"history_days": n, "min_history_days": settings.min_history_days,
            "enough": enough, "healthy_base_rate": settings.healthy_base_rate,
            "cap": None if enough else settings.cap_without_history,
            "judged_by": ("the plant's history days" if n >= 2 else
                          "fallback constants fitted on the virtual plant (posterior."
                          "TEMPERATURE, CONTAMINATION)"),
            "method": None if normal is None else normal.method}


def after_shapes(v: Verdict, cands: list[Candidate], scores: dict[str, Score],
                 skipped: Iterable[str] = ()) -> Verdict:
    """The verdict once the shapes have competed and the probabilities are judged
    (:func:`~.posterior.posterior`'s ``cands``, most probable first): the most probable
    candidate names the cause. Where that is the verdict's own cause (a shape larger than
    the winning extension of its own cause names nothing new: the extension, held-out gain
    and all, stays the verdict) nothing changes; an eligible extension of another cause
    becomes the winner; otherwise the cause is named without a winning extension
    (:func:`named_by_shape`: a shape, or ``none`` or ``unexplained`` where the plant's
    normal says the day's evidence is what its healthy days show)."""
    if not cands or cands[0].cause == v.cause:
        return v
    top = cands[0]
    named = named_by_shape(v, cands, scores, skipped)
    sc = scores.get(top.cause)
    if top.source == "extension" and sc is not None and sc.eligible:
        return Verdict(top.cause, sc, named.ranking, v.structure)
    return named


def named_by_shape(v: Verdict, cands: list[Candidate], scores: dict[str, Score],
                   skipped: Iterable[str] = ()) -> Verdict:
    """The verdict when a cause's shape (:mod:`.shapes`) has the most evidence of all
    (``cands[0]``): that cause named without a winning extension (its model extension,
    where fitted, was not eligible: the held-out numbers stay the baseline's), and the
    ranking every candidate in ``cands``' order with its posterior probability as its
    score, so that the scores are on one scale and sum to one (the verdict's own weights
    are a softmax of the extensions' gains alone); a ``skipped`` cause (not fitted) ranks
    with its probability too, without a score."""
    gone = set(skipped)
    ranking = [(c.cause, c.probability, None if c.cause in gone else scores.get(c.cause))
               for c in cands]
    return Verdict(cands[0].cause, None, ranking, v.structure)
