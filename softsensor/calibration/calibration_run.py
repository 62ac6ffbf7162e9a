"""Calibrate: the paper's section 3 as one function,
:func:`~softsensor.calibration.calibration_run.calibrate`, and its result.

:func:`calibrate` takes the calibration segments (the recorded days, cut to their calibration
windows by :mod:`.selection`), holds out the end of each (``holdout_fraction``) unless other
days are given for validation, runs the Optuna study on the rest (:mod:`.optimize`), polishes
its best trial (:mod:`.refine`), and validates the result against the current parameters on
the held-out data (:mod:`.validation`): a result that predicts worse than the current
parameters is marked not accepted, with the numbers, and the ``calibrate`` verb then refuses
to write it. Unless told not to, it analyses which parameters the data pin down
(:mod:`.identifiability`).

What is minimised is :mod:`.objective`: eq. 4 or the likelihood, after the unmeasured inlet
moisture's trajectory, plus a prior on the parameters (``[calibration]``,
:class:`~.settings.CalibrationSettings`; :func:`objective_spec` sets it up once per
calibration). What the validation leaves on the held-out data
(:func:`~.validation.discrepancy_prior`) goes into PARAMS.toml for the estimator.

The command-line verbs in :mod:`softsensor.apps.calibrate` only parse arguments and print or
write what these return.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import optuna

from softsensor.calibration.chunked_run import ChunkedRun, evaluate_parameters
from softsensor.calibration.cost import ModelRun, weighted_rmse
from softsensor.calibration.dataset import Segment
from softsensor.calibration.disturbance import InletPrior
from softsensor.calibration.identifiability import (
    PAPER_CONDITION_NUMBER,
    Identifiability,
    Sensitivities,
    identify,
    parameter_importance,
)
from softsensor.calibration.objective import (
    Evaluation,
    ObjectiveSpec,
    effective_ratio,
    prior_scale,
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
from softsensor.calibration.selection import WindowChoice
from softsensor.calibration.settings import CalibrationSettings
from softsensor.calibration.trade_off import FrontPoint, TradeOff, scored, study_front
from softsensor.calibration.validation import (
    ValidationResult,
    discrepancy_prior,
    split_holdout,
    validate_many,
)
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, DiscrepancyPrior, PlantConfig, with_table
from softsensor.signals import OUTPUT_NAMES


def objective_spec(model: DryerModel, segments: Sequence[Segment], config: PlantConfig,
                   settings: CalibrationSettings) -> ObjectiveSpec:
    """The objective of a calibration (:mod:`.objective`): the settings, with the prior's
    scale and the effective sample sizes set once at the config's parameter values."""
    inlet = (InletPrior(settings.inlet_knot_hours, settings.inlet_level_std,
                        settings.inlet_walk) if settings.inlet == "estimated" else None)
    center = np.log(config.parameter_vector()) if settings.prior else None
    spec = ObjectiveSpec(cost=settings.cost, weights=config.cost.weights(),
                         prior_center=center, prior_sigma=settings.prior_sigma, inlet=inlet)
    ev0 = evaluate_parameters(model, segments, config.parameter_vector(), spec)[0]
    if ev0.failed:
        return spec
    ratio = effective_ratio(ev0, segments) if settings.cost == "likelihood" else np.ones(3)
    return dataclasses.replace(spec, prior_scale=prior_scale(settings.cost, ev0, spec.weights),
                               n_eff_ratio=ratio)


def at_bounds(theta: np.ndarray, bounds: np.ndarray, margin: float) -> list[str]:
    """Parameters within ``margin`` of a bound (``value <= low (1 + m)`` or ``>= high /
    (1 + m)``)."""
    return [n for n, v, (lo, hi) in zip(PARAMETER_NAMES, theta, bounds, strict=True)
            if v <= lo * (1.0 + margin) or v >= hi / (1.0 + margin)]


@dataclass
class CalibrationResult:
    """Everything a calibration produced (see :func:`calibrate`)."""

    config: PlantConfig
    theta: np.ndarray
    evaluation: Evaluation
    spec: ObjectiveSpec
    calibration: CalibrationSettings
    segments: list[Segment]
    choices: list[WindowChoice]
    study: optuna.Study
    settings: StudySettings
    runs: list[ModelRun]
    tpe_best: dict[str, Any]
    current_theta: np.ndarray
    current_evaluation: Evaluation | None
    refinement: Refinement | None
    identifiability: Identifiability | None
    importance: dict[str, float] | None
    validation: ValidationResult | None = None
    current_validation: ValidationResult | None = None
    discrepancy: DiscrepancyPrior | None = None
    sensitivities: list[Sensitivities] | None = None
    timings: dict[str, float] = field(default_factory=dict)
    trials_here: int = 0
    pruned_here: int = 0
    trade_off: TradeOff | None = None

    @property
    def fit(self):
        return self.evaluation.fit

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(PARAMETER_NAMES, map(float, self.theta), strict=True))

    @property
    def at_bounds(self) -> list[str]:
        """Parameters that ended within the bound margin of a Table 1 bound (flagged)."""
        return at_bounds(self.theta, self.config.bounds(), self.calibration.bound_margin)

    def calibrated_config(self) -> PlantConfig:
        """The config with the calibrated values and the ``[discrepancy]`` the validation
        left, as :func:`~softsensor.plantconfig.load_parameters` reads them back from the
        PARAMS.toml this result writes."""
        cfg = self.config.with_parameters(self.theta)
        if self.discrepancy is None:
            return cfg
        return with_table(cfg, "discrepancy", self.discrepancy.as_table())

    @property
    def accepted(self) -> bool:
        """False when the result predicts the validation data worse than the current
        parameters (then the verb does not write it)."""
        if self.validation is None or self.current_validation is None:
            return True
        return bool(self.validation.score <= self.current_validation.score)

    def verdict_line(self) -> str:
        """One line: validation against the current parameters, and the flags."""
        parts = []
        if self.validation is not None and self.current_validation is not None:
            new, old = self.validation, self.current_validation
            parts.append(
                f"validation on {sum(seg.hours for seg in new.segments):.1f} h held out: "
                f"calibrated "
                f"{_rmse_text(new.fit.rmse)} (score {new.score:.4g}) against current "
                f"{_rmse_text(old.fit.rmse)} (score {old.score:.4g})")
        flags = self.at_bounds
        parts.append("at a bound: " + (", ".join(flags) if flags else "none"))
        return "; ".join(parts)

    def fit_section(self) -> dict[str, Any]:
        """The ``[fit]`` section of PARAMS.toml."""
        s = study_summary(self.study)
        c = s["counts"]
        w = self.config.cost.weights()
        out: dict[str, Any] = {
            "cost_kind": self.spec.cost,
            "objective": self.evaluation.objective,
            "cost": self.fit.cost,
            "prior": self.calibration.prior,
            "prior_sigma": self.calibration.prior_sigma,
            "inlet": self.calibration.inlet,
            "trials": s["finished"],
            "trials_complete": c.get("complete", 0),
            "trials_pruned": c.get("pruned", 0),
            "best_trial": s.get("best_trial"),
            "tpe_best_objective": self.tpe_best.get("objective"),
            "tpe_best_trial": self.tpe_best.get("trial"),
            "refined": bool(self.refinement and self.refinement.improved),
            "seed": self.settings.seed,
            "study_name": self.settings.study_name,
            "storage": self.settings.storage or "",
            "days": sorted({seg.source.split("[")[0] for seg in self.segments}),
            "windows": [seg.source for seg in self.segments],
            "selection": [ch.reason for ch in self.choices],
            "hours": float(sum(seg.hours for seg in self.segments)),
            "at_bounds": self.at_bounds,
            "accepted": self.accepted,
        }
        if self.current_evaluation is not None:
            out["cost_at_current"] = self.current_evaluation.fit.cost
        out["rmse"] = {k: self.fit.rmse[k] for k in OUTPUT_NAMES}
        out["open_loop_rmse"] = {k: self.evaluation.open_fit.rmse[k] for k in OUTPUT_NAMES}
        out["weighted_rmse"] = weighted_rmse(self.fit, w)
        out["weights"] = dict(zip(OUTPUT_NAMES, map(float, w), strict=True))
        out["samples"] = dict(self.fit.n)
        if self.validation is not None:
            out["validation"] = _validation_section(self.validation, self.current_validation)
        if self.identifiability is not None:
            ident = self.identifiability
            out["identifiability"] = {
                "identifiable": ident.identifiable,
                "poorly_identifiable": ident.poorly_identifiable,
                "fim_condition_number": min(ident.condition_number, 1e300),
                "paper_condition_number": PAPER_CONDITION_NUMBER,
            }
        return out

    def summary(self) -> dict[str, Any]:
        """The JSON the ``calibrate`` verb writes."""
        s = study_summary(self.study)
        out = {
            "params": self.params,
            "objective": self.evaluation.objective,
            "cost_kind": self.spec.cost,
            "cost": self.fit.cost,
            "rmse": dict(self.fit.rmse),
            "open_loop_rmse": dict(self.evaluation.open_fit.rmse),
            "weighted_rmse": weighted_rmse(self.fit, self.config.cost.weights()),
            "cost_at_current": (None if self.current_evaluation is None
                                else self.current_evaluation.fit.cost),
            "at_bounds": self.at_bounds,
            "accepted": self.accepted,
            "trials": s["finished"],
            "trials_this_process": self.trials_here,
            "pruned_share": s["pruned_share"],
            "tpe_best": self.tpe_best,
            "refined": bool(self.refinement and self.refinement.improved),
            "refine_simulations": 0 if self.refinement is None else self.refinement.simulations,
            "windows": [{"window": ch.segment.source, "reason": ch.reason}
                        for ch in self.choices],
            "fit_windows": [seg.source for seg in self.segments],
            "timings_s": {k: round(v, 2) for k, v in self.timings.items()},
        }
        if self.validation is not None:
            out["validation"] = _validation_section(self.validation, self.current_validation)
        if self.discrepancy is not None:
            out["discrepancy"] = self.discrepancy.as_dict()
        if self.trade_off is not None:
            out["trade_off"] = self.trade_off.as_dict()
        if self.identifiability is not None:
            ident = self.identifiability
            out["identifiability"] = {
                "fim_condition_number": ident.condition_number,
                "paper_condition_number": PAPER_CONDITION_NUMBER,
                **{v.name: {"verdict": v.verdict, "relative_se": v.relative_se,
                            "profile_rise": v.rise, "reason": v.reason}
                   for v in ident.verdicts}}
        if self.importance is not None:
            out["importance"] = self.importance
        return out


def _rmse_text(rmse: dict[str, float]) -> str:
    return (f"{rmse['T_dryer_out']:.2f}/{rmse['T_cyclone_out']:.2f} K, "
            f"{rmse['moisture_out']:.4f} kg/kg")


def _validation_section(new: ValidationResult, old: ValidationResult | None
                        ) -> dict[str, Any]:
    out: dict[str, Any] = {"windows": [s.source for s in new.segments],
                           "rmse": dict(new.fit.rmse), "score": new.score,
                           "open_loop_rmse": dict(new.evaluation.open_fit.rmse)}
    if old is not None:
        out["current_rmse"] = dict(old.fit.rmse)
        out["current_score"] = old.score
        out["current_open_loop_rmse"] = dict(old.evaluation.open_fit.rmse)
    return out


@contextmanager
def phase(name: str, timings: dict[str, float], say: Callable[[str], None]) -> Iterator[None]:
    """Announce a calibration phase and record its wall time in ``timings[name]`` and the
    CPU time of every thread of the process in ``timings[name + "_cpu"]`` [s]: on a shared
    machine the wall time depends on the load, the CPU time much less."""
    say(name)
    w0, c0 = time.perf_counter(), time.process_time()
    yield
    timings[name] = time.perf_counter() - w0
    timings[f"{name}_cpu"] = time.process_time() - c0


def _tpe_best(study: optuna.Study) -> tuple[np.ndarray, dict[str, Any]]:
    """The study's best parameters and where TPE found them."""
    best = study.best_trial
    return theta_of(best.params), {"trial": best.number, "objective": best.value,
                                   "first_reached": first_trial_reaching(study, best.value)}


def _polish(study: optuna.Study, model: DryerModel, fit_segs: Sequence[Segment],
            theta: np.ndarray, config: PlantConfig, spec: ObjectiveSpec,
            jac_model: DryerModel, calibration: CalibrationSettings) -> Refinement:
    """Refine TPE's best point (the Jacobians from ``jac_model``, the search's); an
    improvement joins the study as a trial (user attribute ``origin = "refine"``), so that
    the study's best trial is the result."""
    refinement = refine(model, fit_segs, theta, config.bounds(), spec, jac_model=jac_model,
                        passes=calibration.polish_passes,
                        max_nfev=calibration.polish_evaluations)
    if refinement.improved:
        study.add_trial(optuna.trial.create_trial(
            params=dict(zip(PARAMETER_NAMES, map(float, refinement.theta), strict=True)),
            distributions=search_space(config), value=refinement.evaluation.objective,
            user_attrs={"origin": "refine", "simulations": refinement.simulations}))
    return refinement


def _validate_both(held: Sequence[Segment], config: PlantConfig, spec: ObjectiveSpec,
                   theta: np.ndarray, current: np.ndarray, fit_cost: float,
                   model: DryerModel, front: Sequence[FrontPoint] = ()
                   ) -> tuple[ValidationResult, ValidationResult, DiscrepancyPrior,
                              list[ValidationResult]]:
    """The result and the current parameters on the held-out data, the result's
    discrepancy there (the [discrepancy] the estimator and the diagnosis use), and the
    ``front`` points' validations, all in one batched run."""
    thetas = [theta, current, *(p.theta for p in front)]
    vals = validate_many(held, config, spec, thetas, [fit_cost] + [None] * (len(thetas) - 1),
                         model)
    return vals[0], vals[1], discrepancy_prior(vals[0].evaluation, held), vals[2:]


def _trade_off(study: optuna.Study, held: Sequence[Segment], config: PlantConfig,
               spec: ObjectiveSpec, calibration: CalibrationSettings, theta: np.ndarray,
               current: np.ndarray, evs: Sequence[Evaluation], model: DryerModel
               ) -> tuple[ValidationResult, ValidationResult, DiscrepancyPrior, TradeOff]:
    """:func:`_validate_both` with the study's front beside (:mod:`.trade_off`)."""
    front = study_front(study)
    val, cur_val, disc, front_vals = _validate_both(held, config, spec, theta, current,
                                                    evs[0].fit.cost, model, front)
    fixed = [FrontPoint("deployed", theta, dict(evs[0].fit.rmse)),
             FrontPoint("current", current, dict(evs[1].fit.rmse))]
    points = scored(fixed + front, [v.evaluation for v in (val, cur_val, *front_vals)])
    return val, cur_val, disc, TradeOff(points, calibration.temperature_target,
                                        calibration.moisture_target)


def search_model(model: DryerModel, calibration: CalibrationSettings) -> DryerModel:
    """``model`` with the search's wall substeps (``calibration.search_wall_substeps``): a
    shallow copy sharing the geometry, or ``model`` itself when they are the same."""
    n = calibration.search_wall_substeps
    if n == 0 or n == model.wall_substeps:
        return model
    fast = copy.copy(model)
    fast.wall_substeps = n
    return fast


def calibrate(segments: Sequence[Segment], config: PlantConfig, settings: StudySettings,
              calibration: CalibrationSettings, *, choices: Sequence[WindowChoice] = (),
              validation_segments: Sequence[Segment] | None = None,
              current_theta: np.ndarray | None = None, polish: bool = True,
              identify_result: bool = True, model: DryerModel | None = None,
              progress: Any = None) -> CalibrationResult:
    """Fit the seven parameters (see the module docstring).

    ``validation_segments``: days to validate on (default: the held-out ends of
    ``segments``, :func:`split_holdout`). ``current_theta``: the parameters the result must
    beat there (default: the config's values). ``progress(phase)`` is called at the start of
    each phase. The returned parameters are the best of the study's trials and the polished
    point; the polished point is added to the study as a trial (user attribute ``origin =
    "refine"``) so that the study's best trial is the result.
    """
    settings.check()
    model = model or DryerModel(config)
    say = progress or (lambda phase: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    fit_segs, held = (split_holdout(segments, calibration.holdout_fraction)
                      if validation_segments is None
                      else (list(segments), list(validation_segments)))
    current = config.parameter_vector() if current_theta is None else np.asarray(current_theta)
    fast = search_model(model, calibration)
    with phase("study", timings, say):
        spec = objective_spec(model, fit_segs, config, calibration)
        study, _ = open_study(settings, config, data_fingerprint(fit_segs, config, spec))
        report = run_trials(study, fast, fit_segs, config, settings, spec)
    theta, tpe_best = _tpe_best(study)
    refinement = None
    if polish:
        with phase("refine", timings, say):
            refinement = _polish(study, model, fit_segs, theta, config, spec, fast,
                                 calibration)
        if refinement.improved:
            theta = refinement.theta
    run = ChunkedRun(model, fit_segs, np.stack([theta, current]), spec, n_chunks=1)
    evs = run.run()
    runs = run.model_lines(0, evs[0])
    val = cur_val = disc = trade = None
    if held:
        with phase("validate", timings, say):
            val, cur_val, disc, trade = _trade_off(study, held, config, spec, calibration,
                                                   theta, current, evs, model)
    ident = importance = sens = None
    if identify_result:
        with phase("identify", timings, say):
            ident, sens = identify(model, fit_segs, theta, spec, config.bounds(),
                                   jac_model=fast)
            importance = parameter_importance(study)
    timings["total"] = time.perf_counter() - t0
    return CalibrationResult(
        config=config, theta=theta, evaluation=evs[0], spec=spec, calibration=calibration,
        segments=list(fit_segs), choices=list(choices), study=study, settings=settings,
        runs=runs, tpe_best=tpe_best, current_theta=current, current_evaluation=evs[1],
        refinement=refinement, identifiability=ident, importance=importance, validation=val,
        current_validation=cur_val, discrepancy=disc, sensitivities=sens, timings=timings,
        trials_here=report.trials, pruned_here=report.pruned, trade_off=trade)


__all__ = ["CalibrationResult", "at_bounds", "calibrate", "objective_spec", "phase",
           "search_model"]
