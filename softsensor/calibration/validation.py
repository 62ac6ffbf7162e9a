"""Validation: a parameter set scored on data it was not fitted on.

:func:`split_holdout` cuts the end of every calibration segment off for validation (unless
other days are given). :func:`validate` scores a parameter set there with the unmeasured inlet
moisture's trajectory fitted to the temperatures only, so that the lab results test the model
out of sample, as the virtual sensor meets them; the open-loop numbers (nominal inlet
moisture) are reported beside. :func:`validate_many` scores several sets in one batched run
(:func:`~.calibration_run.calibrate` compares its result with the current parameters and the
study's front that way).

The statistics of what the validation leaves (:func:`discrepancy_prior`) go into PARAMS.toml's
``[discrepancy]`` (:class:`~softsensor.plantconfig.DiscrepancyPrior`) for the estimator: how
far, how correlated and how slowly the calibrated model misses a day it was not fitted on.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.calibration.chunked_run import ChunkedRun
from softsensor.calibration.cost import ModelRun, weighted_rmse
from softsensor.calibration.dataset import Segment
from softsensor.calibration.identifiability import lag1_autocorrelation
from softsensor.calibration.objective import Evaluation, ObjectiveSpec
from softsensor.model import DryerModel
from softsensor.plantconfig import DiscrepancyPrior, PlantConfig

#: Lab samples a held-out part must hold to validate on it.
MIN_HELD_LABS = 2



def split_holdout(segments: Sequence[Segment], fraction: float,
                  min_labs: int = MIN_HELD_LABS) -> tuple[list[Segment], list[Segment]]:
    """Cut the last ``fraction`` of every segment off for validation. A segment whose tail
    would hold fewer than ``min_labs`` lab results (or whose head would hold none) is kept
    whole for fitting. Returns ``(fit, held)``."""
    fit, held = [], []
    for seg in segments:
        k = int(round((1.0 - fraction) * seg.n_windows))
        if fraction <= 0 or k < 1 or k >= seg.n_windows:
            fit.append(seg)
            continue
        n_head = seg.labs_before(k)
        if n_head < 1 or len(seg.lab_value) - n_head < min_labs:
            fit.append(seg)
            continue
        fit.append(seg.slice(0, k))
        held.append(seg.slice(k, seg.n_windows))
    return fit, held


def discrepancy_prior(ev: Evaluation, segments: Sequence[Segment]) -> DiscrepancyPrior:
    """PARAMS.toml's ``[discrepancy]`` (:class:`~softsensor.plantconfig.DiscrepancyPrior`,
    whose attributes say what each number is) from a validation evaluation (residuals per
    segment). A number these data cannot give (fewer than two windows, no lab result, no inlet
    knot) is None: not known."""
    pairs_d, pairs_c, rhos = [], [], []
    for r, seg in zip(ev.res, segments, strict=True):
        ok = np.isfinite(seg.Y[:, 0]) & np.isfinite(seg.Y[:, 1])
        okd, okc = np.isfinite(seg.Y[:, 0]), np.isfinite(seg.Y[:, 1])
        rd = np.full(seg.n_windows, np.nan)
        rc = np.full(seg.n_windows, np.nan)
        rd[okd] = r[0]
        rc[okc] = r[1]
        pairs_d.append(rd[ok])
        pairs_c.append(rc[ok])
        rhos.append(lag1_autocorrelation(0.5 * (rd + rc)[ok]))
    d = np.concatenate(pairs_d) if pairs_d else np.zeros(0)
    c = np.concatenate(pairs_c) if pairs_c else np.zeros(0)
    if d.size >= 2:
        # second moments about zero, not about the mean: the model's error on a day it was not
        # fitted on includes its mean offset, which the estimator must expect too
        cross = float(np.mean(d * c))
        common = math.sqrt(max(cross, 0.0))
        own_d = math.sqrt(max(float(np.mean(d * d)) - max(cross, 0.0), 0.0))
        own_c = math.sqrt(max(float(np.mean(c * c)) - max(cross, 0.0), 0.0))
    else:
        common = own_d = own_c = float("nan")
    rho = float(np.clip(np.mean(rhos), 1e-3, 0.999)) if rhos else 0.5
    window = segments[0].window if segments else 600.0
    tau = -window / math.log(rho)
    labs = np.concatenate([r[2] for r in ev.res]) if ev.res else np.zeros(0)
    walks = []
    for cs, kn in zip(ev.inlet, ev.knots, strict=True):
        if cs.size > 1:
            walks.append(np.diff(cs) / np.sqrt(np.diff(kn)))
    walk = float(np.sqrt(np.mean(np.concatenate(walks) ** 2))) if walks else float("nan")
    moisture = float(np.sqrt(np.mean(labs**2))) if labs.size else math.nan
    return DiscrepancyPrior(
        common_std=_known(common), dryer_std=_known(own_d), cyclone_std=_known(own_c),
        tau_s=_known(tau), moisture_std=_known(moisture), inlet_walk=_known(walk),
        n_windows=float(d.size), n_labs=float(labs.size))


def _known(x: float) -> float | None:
    """``x``, or None (not known) when it is not finite."""
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class ValidationResult:
    """A parameter set evaluated on data it was not fitted on.

    ``evaluation``: with the inlet trajectory fitted to the temperatures only (the lab results
    out of sample); its ``open_fit`` is the model with the nominal inlet moisture.
    """

    theta: np.ndarray
    evaluation: Evaluation
    segments: list[Segment]
    runs: list[ModelRun]
    weights: np.ndarray
    calibration_cost: float | None = None

    @property
    def fit(self):
        return self.evaluation.fit

    @property
    def score(self) -> float:
        """The data term of the calibration's cost on these data (lower is better)."""
        return self.evaluation.data

    @property
    def ratio(self) -> float | None:
        """Validation eq. 4 over calibration eq. 4 (None when the latter is unknown)."""
        if not self.calibration_cost:
            return None
        return self.fit.cost / self.calibration_cost

    def inlet_read(self) -> dict[str, Any]:
        """The scores with the inlet trajectory read from the temperatures (``validate``'s
        JSON ``inlet_read``; its ``open_loop`` is :mod:`.open_loop_errors`'s)."""
        ev = self.evaluation
        return {"rmse": dict(ev.fit.rmse), "weighted_rmse": weighted_rmse(ev.fit, self.weights),
                "cost": ev.fit.cost, "score": ev.data, "samples": dict(ev.fit.n),
                "inlet_moisture_offset": [float(np.mean(c)) if c.size else 0.0
                                          for c in ev.inlet],
                "calibration_cost": self.calibration_cost, "cost_ratio": self.ratio}


def validate_many(segments: Sequence[Segment], config: PlantConfig, spec: ObjectiveSpec,
                  thetas: Sequence[np.ndarray], calibration_costs: Sequence[float | None],
                  model: DryerModel) -> list[ValidationResult]:
    """:func:`validate` of several parameter sets through one batched run (the members run
    on the model's threads; each gets the numbers it gets alone)."""
    for seg in segments:
        seg.require_labs(1)
    vspec = dataclasses.replace(spec, inlet_from_labs=False)
    run = ChunkedRun(model, segments, np.stack([np.asarray(t, float) for t in thetas]), vspec,
                     n_chunks=1)
    evs = run.run()
    return [ValidationResult(theta=np.asarray(t, float), evaluation=ev, segments=list(segments),
                             runs=run.model_lines(b, ev), weights=config.cost.weights(),
                             calibration_cost=cost)
            for b, (t, ev, cost) in enumerate(zip(thetas, evs, calibration_costs, strict=True))]


def validate(segments: Sequence[Segment], config: PlantConfig, spec: ObjectiveSpec,
             theta: np.ndarray | None = None, calibration_cost: float | None = None,
             model: DryerModel | None = None) -> ValidationResult:
    """Score ``theta`` (default: the config's values) on ``segments`` with the inlet
    trajectory fitted to the temperatures only (module docstring). Its ``runs`` hold the
    model with that trajectory (row 0, what the scores compare) and open loop (row 1)."""
    model = model or DryerModel(config)
    theta = config.parameter_vector() if theta is None else np.asarray(theta, float)
    return validate_many(segments, config, spec, [theta], [calibration_cost], model)[0]

__all__ = ["MIN_HELD_LABS", "ValidationResult", "discrepancy_prior", "split_holdout", "validate",
           "validate_many"]
