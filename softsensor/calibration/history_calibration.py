"""Calibration from the plant's history: shared physics, per-day inlet levels, the learned
model error.

A plant hands over weeks of clean days, not one. :func:`calibrate_history` takes them as
whole-day :class:`~.dataset.Segment` s and

1. picks the calibration windows by natural variability *across* the days
   (:func:`~.selection.select_across`, ``window_hours`` each, ``fit_hours`` in all): the
   study's cost grows with the hours it simulates, not with the days handed over;
2. fits the seven Table 1 parameters on them with :func:`~.calibration_run.calibrate` (each window
   its own inlet-moisture trajectory: every day its own level), and validates the result
   against the current parameters on the rest of every day (each day's hours not used for
   fitting, in pieces of at least :data:`MIN_VALIDATION_HOURS` holding lab results), pooled;
   with a single day, on its held-out tail;
3. keeps the current parameters when the result predicts the held-out data worse (unless
   ``force``): either way there is a parameter set to deploy;
4. at the deployed parameters, fits every day's inlet-moisture level (the calibration's
   trajectory on the whole day, temperatures and labs) and learns the model's error from all
   days (:func:`~.model_error_fit.fit_model_error`, validated leave one day out): the
   history gives the normal (the error's slopes, spreads and wander), the latest day the
   state (its inlet level, where the estimator starts).

Everything after the study is one or two simulations of the history, so the time grows
linearly with the days. The lab regression, the estimator's peer beside the physics, is fitted
on the same days (:func:`history_regression`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.calibration.calibration_run import CalibrationResult, calibrate, phase
from softsensor.calibration.chunked_run import evaluate_parameters
from softsensor.calibration.dataset import DayLike, Segment
from softsensor.calibration.model_error_fit import fit_model_error
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.selection import WindowChoice, select_across, select_windows
from softsensor.calibration.sensor_score import (
    SCORE_DAYS,
    deployable,
    latest_days,
    not_worse,
    paired,
    sensor_score,
)
from softsensor.calibration.settings import CalibrationSettings
from softsensor.calibration.structure_search import Candidate, StructureSearch
from softsensor.calibration.structure_search import search as structural_search
from softsensor.calibration.validation import MIN_HELD_LABS, discrepancy_prior
from softsensor.errors import ConfigError
from softsensor.estimation.lab_regression import (
    REGRESSION_SIGNALS,
    LabRegression,
    fit_lab_regression,
    lab_features,
)
from softsensor.estimation.model_error import ModelError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, DiscrepancyPrior, PlantConfig

#: Shortest piece of a day's unused hours that validates [h].
MIN_VALIDATION_HOURS = 4.0


@dataclass
class HistoryResult:
    """What a calibration from history produced.

    ``calibration``: the study's result (its ``theta`` the calibrated parameters);
    ``theta``: the parameters to deploy (the calibrated ones, or the current ones kept);
    ``kept_current`` and ``reason``: whether and why the current ones were kept;
    ``inlet_levels``: each day's fitted inlet moisture [kg/kg]; ``model_error``: learned at
    ``theta``; ``discrepancy``: what ``theta`` leaves on the held-out data (the heat input's
    prior); ``structure``: the structural search (:mod:`.structure_search`), when it ran;
    ``sensor_accept``: why the sensor's lab score let a fit whose held-out labs got worse be
    deployed, or kept the current parameters (None when the labs did not get worse).
    """

    calibration: CalibrationResult
    theta: np.ndarray
    kept_current: bool
    reason: str
    inlet_levels: list[float]
    model_error: ModelError
    discrepancy: DiscrepancyPrior | None
    timings: dict[str, float] = field(default_factory=dict)
    structure: StructureSearch | None = None
    sensor_accept: str | None = None

    @property
    def params(self) -> dict[str, float]:
        return dict(zip(PARAMETER_NAMES, map(float, self.theta), strict=True))

    def summary(self) -> dict[str, Any]:
        me = self.model_error
        return {"kept_current": self.kept_current, "reason": self.reason,
                "deployed_params": self.params, "inlet_levels": self.inlet_levels,
                "model_error": {
                    "days": me.days, "hours": me.hours, "moisture_in": me.moisture_in,
                    "moisture_in_day_sd": me.moisture_in_day_sd,
                    "latest_moisture_in": me.latest_moisture_in,
                    **{c: {"learned": me.channel(c).learned,
                           "rmse_without": me.channel(c).rmse_without,
                           "rmse_held_out": me.channel(c).rmse_held_out,
                           "day_sd": me.channel(c).day_sd, "walk": me.channel(c).walk,
                           "noise": me.channel(c).noise}
                       for c in ("T_dryer_out", "T_cyclone_out", "moisture_out")}},
                "structure": None if self.structure is None else self.structure.as_dict(),
                "sensor_accept": self.sensor_accept,
                "timings_s": {k: round(v, 2) for k, v in self.timings.items()}}


def validation_pieces(days: Sequence[Segment], choices: Sequence[WindowChoice],
                      min_hours: float = MIN_VALIDATION_HOURS,
                      min_labs: int = MIN_HELD_LABS) -> list[Segment]:
    """Every day's hours not chosen for fitting, as segments of at least ``min_hours``
    holding ``min_labs`` lab results."""
    out = []
    for i, seg in enumerate(days):
        free = np.ones(seg.n_windows, dtype=bool)
        for c in choices:
            if c.day == i:
                free[c.k0:c.k1] = False
        n_min = int(math.ceil(min_hours * 3600.0 / seg.window))
        k = 0
        while k < seg.n_windows:
            if not free[k]:
                k += 1
                continue
            k1 = k
            while k1 < seg.n_windows and free[k1]:
                k1 += 1
            piece = seg.slice(k, k1)
            if k1 - k >= n_min and len(piece.lab_value) >= min_labs:
                out.append(piece)
            k = k1
    return out


def choose_windows(days: Sequence[Segment], window_hours: float, fit_hours: float,
                   min_labs: int, windows_per_day: int = 1
                   ) -> tuple[list[WindowChoice], list[Segment] | None]:
    """The calibration windows and the validation data: one day, its ``windows_per_day``
    best windows and (None) their held-out tails; several days, windows across them and the
    rest of every day."""
    if len(days) == 1:
        return select_windows(days[0], window_hours, windows_per_day, min_labs), None
    choices = select_across(list(days), window_hours, fit_hours, min_labs)
    held = validation_pieces(days, choices)
    return choices, held or None


def inlet_levels(model: DryerModel, days: Sequence[Segment], theta: np.ndarray,
                 calibration: CalibrationResult) -> list[float]:
    """Each day's inlet moisture at ``theta`` [kg/kg]: the nominal plus the mean of the
    calibration's trajectory fitted to the whole day (temperatures and labs)."""
    spec = dataclasses.replace(calibration.spec, inlet_from_labs=True)
    nominal = float(calibration.config.nominal.moisture_in)
    if spec.inlet is None:
        return [nominal] * len(days)
    ev = evaluate_parameters(model, days, theta, spec)[0]
    return [nominal + (float(np.mean(c)) if c.size else 0.0) for c in ev.inlet]


def calibrate_history(days: Sequence[Segment], config: PlantConfig, settings: StudySettings,
                      calibration: CalibrationSettings, *, current_theta: np.ndarray,
                      window_hours: float, fit_hours: float, min_labs: int = 3,
                      windows_per_day: int = 1, polish: bool = True,
                      identify_result: bool = True, force: bool = False,
                      validation: Sequence[Segment] | None = None,
                      model: DryerModel | None = None,
                      structure: Sequence[Candidate] | None = None,
                      progress: Callable[[str], None] | None = None) -> HistoryResult:
    """Calibrate on the history ``days`` (module docstring); ``validation``: days to validate
    on instead of the held-out hours; ``structure``: the structural alternatives to search
    (:mod:`.structure_search`; None or empty: the paper's form only)."""
    say = progress or (lambda phase: None)
    model = model or DryerModel(config)
    t0, c0 = time.perf_counter(), time.process_time()
    choices, held = choose_windows(days, window_hours, fit_hours, min_labs, windows_per_day)
    if validation:
        held = list(validation)
    result = calibrate([c.segment for c in choices], config, settings, calibration,
                       choices=choices, validation_segments=held, current_theta=current_theta,
                       polish=polish, identify_result=identify_result, model=model,
                       progress=progress)
    timings = dict(result.timings)
    kept = not (result.accepted or force)
    theta = np.asarray(current_theta if kept else result.theta, float)
    reason = ("the calibrated parameters predict the held-out data worse than the current "
              f"ones ({result.verdict_line()})" if kept else
              "calibrated" + ("" if result.accepted else " (forced, though they predict the "
                                                         "held-out data worse)"))
    # what sensor_decides learned for each side, by name ("baseline" or the alternative's),
    # and the side deployed
    learned: dict[str, tuple[list[float], ModelError]] = {}
    accept_why = None
    if not kept and not force and labs_worse(result):
        # accepted on the weighted cost of all channels while its held-out labs got worse:
        # the sensor's own lab score on the latest days decides (issue 47)
        with phase("sensor_accept", timings, say):
            better, why = sensor_accepts(days, config, model, result,
                                         np.asarray(current_theta, float), learned)
        if not better:
            kept, theta = True, np.asarray(current_theta, float)
            reason = accept_why = (
                "the calibrated parameters predict the held-out lab results worse than the "
                f"current ones and the sensor's lab score does not say they are better ({why})")
        else:
            accept_why = f"the sensor's lab score on the latest days is better: {why}"
    search = None
    deployed = "baseline"
    # only against a polished baseline: from a study stopped short of the optimum, any change
    # of structure can look better (measured: 3 trials without the polish on a matched plant
    # of the paper's form "adopted" a longer cyclone hold-up by 391 log-likelihood units)
    if structure and polish and result.validation is not None:
        with phase("structure", timings, say):
            search = structural_search(result.segments, result.validation.segments, config,
                                       calibration, theta,
                                       result.validation.evaluation if not kept else
                                       result.current_validation.evaluation,
                                       result.trade_off, structure, say=say)
        if search.adopted is not None:
            with phase("sensor_score", timings, say):
                search = sensor_decides(search, days, config, model, theta, result, learned,
                                        deployed_discrepancy(result, kept))
        if search.adopted is not None:
            deployed = search.adopted.candidate.name
            config = config.with_keys(search.adopted.keys)
            model, theta, kept = DryerModel(config), search.adopted.theta, False
            reason = f"calibrated with the structure '{search.adopted.candidate.name}'"
    with phase("model_error", timings, say):
        # the sensor's decision learned the deployed side's already: the same days and theta
        levels, me = learned.get(deployed) or learned_error(model, days, theta, result)
    disc = deployed_discrepancy(result, kept)
    timings["history_total"] = time.perf_counter() - t0
    timings["history_total_cpu"] = time.process_time() - c0
    return HistoryResult(result, theta, kept, reason, levels, me, disc, timings, search,
                         accept_why)


def deployed_discrepancy(result: CalibrationResult, kept: bool) -> DiscrepancyPrior | None:
    """PARAMS.toml's ``[discrepancy]``: the calibration's, or the current parameters' when
    they are kept (from their own validation on the held-out hours)."""
    if kept and result.current_validation is not None:
        cur = result.current_validation
        return discrepancy_prior(cur.evaluation, cur.segments)
    return result.discrepancy


def learned_error(model: DryerModel, days: Sequence[Segment], theta: np.ndarray,
                  result: CalibrationResult) -> tuple[list[float], ModelError]:
    """Every day's inlet level (:func:`inlet_levels`) and the model error learned on the
    days at ``theta`` with their mean, their spread and the latest day's level."""
    levels = inlet_levels(model, days, theta, result)
    latest = levels[int(np.argmax([d.start_ns for d in days]))]
    return levels, fit_model_error(model, days, theta, float(np.mean(levels)),
                                   float(np.std(levels)) if len(levels) > 1 else 0.0, latest)


def labs_worse(result: CalibrationResult) -> bool:
    """True when the calibrated parameters predict the held-out lab results worse than the
    current ones (the validation's outlet-moisture RMSE)."""
    new, old = result.validation, result.current_validation
    if new is None or old is None:
        return False
    a, b = new.fit.rmse.get("moisture_out"), old.fit.rmse.get("moisture_out")
    return a is not None and b is not None and math.isfinite(a) and math.isfinite(b) and a > b


def sensor_accepts(days: Sequence[Segment], config: PlantConfig, model: DryerModel,
                   result: CalibrationResult, current_theta: np.ndarray,
                   learned: dict[str, tuple[list[float], ModelError]]) -> tuple[bool, str]:
    """Whether the estimator does better with the calibrated parameters than with the current
    ones on the latest days (:mod:`.sensor_score`, lab by lab): a mean log density higher by
    more than the difference's standard error, and no more results it failed to predict.
    Each side deployed as PARAMS.toml would deploy it, its own model error learned on the
    history; the side that wins goes into ``learned`` as ``"baseline"`` (the structure
    search's starting point)."""
    sides = {}
    for name, th, kept in (("calibrated", result.theta, False),
                           ("current", current_theta, True)):
        levels, me = learned_error(model, days, th, result)
        sides[name] = ((levels, me),
                       sensor_score(deployable(config, th, me, deployed_discrepancy(result,
                                                                                     kept)),
                                    latest_days(days)))
    p = paired(sides["calibrated"][1], sides["current"][1])
    better = p.failed_a <= p.failed_b and p.n > 0 and p.diff > p.se
    learned["baseline"] = sides["calibrated" if better else "current"][0]
    return better, (f"{p.diff:+.3f} +- {p.se:.3f} per result on {p.n} results, RMSE "
                    f"{sides['calibrated'][1].rmse:.4f} against "
                    f"{sides['current'][1].rmse:.4f} kg/kg")


def sensor_decides(search: StructureSearch, days: Sequence[Segment], config: PlantConfig,
                   model: DryerModel, theta: np.ndarray, result: CalibrationResult,
                   learned: dict[str, tuple[list[float], ModelError]] | None = None,
                   discrepancy: DiscrepancyPrior | None = None) -> StructureSearch:
    """The structure the held-out evidence chose, kept only when the estimator does at least
    as well with it on the latest days (:mod:`.sensor_score`), lab by lab
    (:func:`~.sensor_score.not_worse`: no more results it failed to predict, and a mean log
    density on the results both predicted not lower by more than the difference's standard
    error; a tie leaves the held-out evidence's choice standing). Each side is
    deployed as PARAMS.toml would deploy it (``discrepancy``, the ``[discrepancy]`` the
    baseline deploys with), its own model error learned on the history
    (:func:`learned_error`; each side's goes into ``learned`` by name, so that the side
    deployed is not learned twice). Both scores and the paired difference go into the
    search's record."""
    adopted = search.adopted
    assert adopted is not None
    alt_config = config.with_keys(adopted.keys)
    scores = {}
    learned = {} if learned is None else learned
    for name, cfg, mdl, th in (("baseline", config, model, theta),
                               (adopted.candidate.name, alt_config, DryerModel(alt_config),
                                adopted.theta)):
        levels, me = learned[name] = learned_error(mdl, days, th, result)
        scores[name] = sensor_score(deployable(cfg, th, me, discrepancy), latest_days(days))
    base, alt = scores["baseline"], scores[adopted.candidate.name]
    p = paired(alt, base)
    record = {"days": min(len(days), SCORE_DAYS),
              **{k: v.as_dict() for k, v in scores.items()}, "paired": p.as_dict()}
    if not_worse(p):
        return dataclasses.replace(search, sensor=record)
    why = (f"it failed to predict {p.failed_a} lab results against {p.failed_b}"
           if p.failed_a > p.failed_b else
           f"{p.diff:+.3f} +- {p.se:.3f} per result on {p.n} results")
    return search.overruled(
        f"the estimator's lab score on the latest days is worse with it ({why}; RMSE "
        f"{alt.rmse:.4f} against {base.rmse:.4f} kg/kg)", record)


def history_regression(days: Sequence[DayLike]) -> tuple[LabRegression | None, str | None]:
    """The lab regression on the history (PARAMS.toml's ``[regression]``, the peer the
    estimator runs beside its physics) on the signals every day scanned, and None; or None
    and why, when the history holds too few lab results for it."""
    signals = [s for s in REGRESSION_SIGNALS
               if all(s in d.scans.columns and d.scans[s].notna().any() for d in days)]
    try:
        return fit_lab_regression([lab_features(d.scans, d.labs, signals) for d in days],
                                  signals), None
    except ConfigError as exc:
        return None, str(exc)


__all__ = ["MIN_VALIDATION_HOURS", "HistoryResult", "calibrate_history", "choose_windows",
           "deployed_discrepancy", "history_regression", "inlet_levels", "labs_worse",
           "learned_error", "sensor_accepts", "sensor_decides", "validation_pieces"]
