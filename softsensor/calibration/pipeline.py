"""Calibrate, identify, validate: the three workflows of the paper's section 3, as functions.

:func:`calibrate` loads the recorded days, picks the calibration window(s) of each
(:mod:`.selection`), runs the Optuna study (:mod:`.optimize`), polishes its best trial
(:mod:`.refine`), evaluates the result on the whole calibration data and, unless told not to,
analyses which parameters the data pin down (:mod:`.identifiability`). :func:`validate`
evaluates a parameter set on an independent day. The command-line verbs in
:mod:`.commands` only parse arguments and print or write what these return.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna

from softsensor.calibration.chunked_run import simulate_segments
from softsensor.calibration.cost import Fit, ModelRun, evaluate_fit, weighted_rmse
from softsensor.calibration.dataset import Segment, load_segment
from softsensor.calibration.identifiability import (
    Identifiability,
    Sensitivities,
    analyse,
    displacement_test,
    noise_from_fit,
    parameter_importance,
    sensitivities,
)
from softsensor.calibration.optimize import (
    StudySettings,
    data_fingerprint,
    first_trial_reaching,
    open_study,
    run_trials,
    search_space,
    study_summary,
    theta_of,
)
from softsensor.calibration.refine import Refinement, refine
from softsensor.calibration.selection import WindowChoice, select_windows
from softsensor.errors import IngestError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import OUTPUT_NAMES

#: The paper's calibration horizon [h].
DEFAULT_WINDOW_HOURS = 48.0
#: Lab samples a calibration window must hold.
DEFAULT_MIN_LABS = 3


@dataclass(frozen=True)
class DataSelection:
    """How the calibration data are taken from the recorded days."""

    window_hours: float = DEFAULT_WINDOW_HOURS
    windows_per_day: int = 1
    min_labs: int = DEFAULT_MIN_LABS


def load_segments(paths: Sequence[str | Path], config: PlantConfig,
                  selection: DataSelection = DataSelection()
                  ) -> tuple[list[Segment], list[WindowChoice]]:
    """Resample every day and pick its calibration window(s)."""
    if not paths:
        raise IngestError("no recorded day given")
    segments, choices = [], []
    for p in paths:
        seg = load_segment(p, config)
        picked = select_windows(seg, selection.window_hours, selection.windows_per_day,
                                selection.min_labs)
        choices += picked
        segments += [c.segment for c in picked]
    return segments, choices


@dataclass
class CalibrationResult:
    """Everything a calibration produced (see :func:`calibrate`)."""

    config: PlantConfig
    theta: np.ndarray
    fit: Fit
    segments: list[Segment]
    choices: list[WindowChoice]
    study: optuna.Study
    settings: StudySettings
    runs: list[ModelRun]
    tpe_best: dict[str, Any]
    config_fit: Fit | None
    refinement: Refinement | None
    identifiability: Identifiability | None
    importance: dict[str, float] | None
    sensitivities: list[Sensitivities] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    trials_here: int = 0
    pruned_here: int = 0

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(PARAMETER_NAMES, map(float, self.theta), strict=True))

    def fit_section(self) -> dict[str, Any]:
        """The ``[fit]`` section of PARAMS.toml."""
        s = study_summary(self.study)
        c = s["counts"]
        w = self.config.cost.weights()
        out: dict[str, Any] = {
            "cost": self.fit.cost,
            "trials": s["finished"],
            "trials_complete": c.get("complete", 0),
            "trials_pruned": c.get("pruned", 0),
            "best_trial": s.get("best_trial"),
            "tpe_best_cost": self.tpe_best.get("cost"),
            "tpe_best_trial": self.tpe_best.get("trial"),
            "refined": bool(self.refinement and self.refinement.improved),
            "seed": self.settings.seed,
            "study_name": self.settings.study_name,
            "storage": self.settings.storage or "",
            "days": sorted({seg.source.split("[")[0] for seg in self.segments}),
            "windows": [seg.source for seg in self.segments],
            "selection": [ch.reason for ch in self.choices],
            "hours": float(sum(seg.hours for seg in self.segments)),
        }
        if self.config_fit is not None:
            out["cost_at_config"] = self.config_fit.cost
        out["rmse"] = {k: self.fit.rmse[k] for k in OUTPUT_NAMES}
        out["weighted_rmse"] = weighted_rmse(self.fit, w)
        out["weights"] = dict(zip(OUTPUT_NAMES, map(float, w), strict=True))
        out["samples"] = dict(self.fit.n)
        if self.identifiability is not None:
            ident = self.identifiability
            out["identifiability"] = {
                "identifiable": ident.identifiable,
                "poorly_identifiable": ident.poorly_identifiable,
                "fim_condition_number": min(ident.condition_number, 1e300),
            }
        return out

    def summary(self) -> dict[str, Any]:
        """The JSON the ``calibrate`` verb prints."""
        s = study_summary(self.study)
        out = {
            "params": self.params,
            "cost": self.fit.cost,
            "rmse": dict(self.fit.rmse),
            "weighted_rmse": weighted_rmse(self.fit, self.config.cost.weights()),
            "cost_at_config": None if self.config_fit is None else self.config_fit.cost,
            "trials": s["finished"],
            "trials_this_process": self.trials_here,
            "pruned_share": s["pruned_share"],
            "tpe_best": self.tpe_best,
            "refined": bool(self.refinement and self.refinement.improved),
            "refine_simulations": 0 if self.refinement is None else self.refinement.simulations,
            "windows": [{"window": ch.segment.source, "reason": ch.reason}
                        for ch in self.choices],
            "timings_s": {k: round(v, 2) for k, v in self.timings.items()},
        }
        if self.identifiability is not None:
            out["identifiability"] = {v.name: {"verdict": v.verdict,
                                               "relative_se": v.relative_se,
                                               "eq4_se": v.eq4_se,
                                               "reason": v.reason}
                                      for v in self.identifiability.verdicts}
        if self.importance is not None:
            out["importance"] = self.importance
        return out


def identify_segments(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                      config: PlantConfig, fit: Fit | None = None,
                      runs: Sequence[ModelRun] | None = None
                      ) -> tuple[Identifiability, list[Sensitivities]]:
    """Sensitivities on every segment and the identifiability analysis at ``theta``."""
    weights = config.cost.weights()
    if runs is None:
        runs = simulate_segments(model, segments, theta)
    if fit is None:
        fit = evaluate_fit(runs, segments, weights)[0]
    sens = [sensitivities(model, seg, theta) for seg in segments]
    noise = noise_from_fit(fit, segments, runs)
    informed = analyse(sens, weights, noise, config.bounds())
    tested = np.array([v.verdict != "not identifiable" for v in informed.verdicts])
    disp = displacement_test(model, segments, theta, sens, fit, runs, weights, noise,
                             config.bounds(), tested)
    return analyse(sens, weights, noise, config.bounds(), disp), sens


def calibrate(segments: Sequence[Segment], config: PlantConfig, settings: StudySettings, *,
              choices: Sequence[WindowChoice] = (), polish: bool = True,
              identify: bool = True, model: DryerModel | None = None) -> CalibrationResult:
    """Fit the seven parameters to ``segments`` (see the module docstring).

    The returned parameters are the best of the study's trials and the polished point; the
    polished point is added to the study as a trial (user attribute ``origin = "refine"``) so
    that the study's best trial is the result.
    """
    settings.check()
    model = model or DryerModel(config)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    study, _created = open_study(settings, config, data_fingerprint(segments, config))
    report = run_trials(study, model, segments, config, settings)
    timings["study"] = time.perf_counter() - t0
    best = study.best_trial
    tpe_best = {"trial": best.number, "cost": best.value,
                "first_reached": first_trial_reaching(study, best.value)}
    theta = theta_of(best.params)
    refinement = None
    if polish:
        t1 = time.perf_counter()
        refinement = refine(model, segments, theta, config.bounds(), config.cost.weights())
        timings["refine"] = time.perf_counter() - t1
        if refinement.improved:
            theta = refinement.theta
            study.add_trial(optuna.trial.create_trial(
                params=dict(zip(PARAMETER_NAMES, map(float, theta), strict=True)),
                distributions=search_space(config), value=refinement.fit.cost,
                user_attrs={"origin": "refine", "simulations": refinement.simulations}))
    runs = simulate_segments(model, segments, theta)
    fit = evaluate_fit(runs, segments, config.cost.weights())[0]
    config_fit = evaluate_fit(simulate_segments(model, segments, model.theta0), segments,
                              config.cost.weights())[0]
    ident = importance = sens = None
    if identify:
        t2 = time.perf_counter()
        ident, sens = identify_segments(model, segments, theta, config, fit, runs)
        importance = parameter_importance(study)
        timings["identify"] = time.perf_counter() - t2
    timings["total"] = time.perf_counter() - t0
    return CalibrationResult(
        config=config, theta=theta, fit=fit, segments=list(segments), choices=list(choices),
        study=study, settings=settings, runs=runs, tpe_best=tpe_best,
        config_fit=config_fit, refinement=refinement, identifiability=ident,
        importance=importance, sensitivities=sens, timings=timings, trials_here=report.trials,
        pruned_here=report.pruned)


@dataclass(frozen=True)
class ValidationResult:
    """A parameter set evaluated on an independent day."""

    fit: Fit
    weighted: dict[str, float]
    segment: Segment
    run: ModelRun
    calibration_cost: float | None

    @property
    def ratio(self) -> float | None:
        """Validation cost over calibration cost (None when the latter is unknown)."""
        if not self.calibration_cost:
            return None
        return self.fit.cost / self.calibration_cost

    def summary(self) -> dict[str, Any]:
        return {"day": self.segment.source, "hours": self.segment.hours,
                "rmse": dict(self.fit.rmse), "weighted_rmse": self.weighted,
                "cost": self.fit.cost, "samples": dict(self.fit.n),
                "calibration_cost": self.calibration_cost, "cost_ratio": self.ratio}


def validate(segment: Segment, config: PlantConfig, calibration_cost: float | None = None,
             model: DryerModel | None = None) -> ValidationResult:
    """Per-channel RMSE and eq. 4 cost of ``config``'s parameters on a whole day."""
    segment.require_labs(1)
    model = model or DryerModel(config)
    Y = simulate_segments(model, [segment], config.parameter_vector())[0]
    fit = evaluate_fit([Y], [segment], config.cost.weights())[0]  # one member
    return ValidationResult(fit=fit, weighted=weighted_rmse(fit, config.cost.weights()),
                            segment=segment, run=Y, calibration_cost=calibration_cost)


__all__ = [
    "DEFAULT_WINDOW_HOURS",
    "CalibrationResult",
    "DataSelection",
    "ValidationResult",
    "calibrate",
    "identify_segments",
    "load_segments",
    "validate",
]
