"""Local polish of the best TPE trial: bounded Gauss-Newton in log-parameter space.

TPE (paper section 3.3) finds the basin but converges slowly inside it: on a virtual-plant
day with known parameters, 200 TPE trials alone stop at about twice the cost at the true
values, with multipliers off by tens of percent along the ridge that ``mult_D`` and ``mult_h``
share. A few trust-region Gauss-Newton steps from the best trial close that gap.

The objective (:mod:`.objective`: eq. 4 or the likelihood, after the inlet trajectory, plus
the prior) is not a sum of squares; it is minimised by iteratively re-weighted least squares:
:func:`~.objective.residual_vector` stacks residuals whose half squared norm has the
objective's gradient at the current point. Each pass minimises that with
:func:`scipy.optimize.least_squares` (trust-region reflective, so Table 1 bounds are never
left) over ``z = ln(theta)``; the weights are refreshed between passes. The Jacobian comes from
forward differences in ``z`` through one batched model call. The result is accepted only if it
lowers the objective.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from softsensor.calibration.chunked_run import evaluate_parameters
from softsensor.calibration.dataset import Segment
from softsensor.calibration.objective import (
    Evaluation,
    ObjectiveSpec,
    irls_scale,
    residual_vector,
)
from softsensor.model import DryerModel

#: Forward-difference step in ln(theta).
FD_STEP = 1e-3
#: Residual entry standing for a failed model solve.
FAILED_RESIDUAL = 1e6
#: A parameter is polished when its weighted sensitivity column norm is at least this
#: fraction of the largest one.
ACTIVE_FRACTION = 1e-3
#: Another re-weighted pass runs only when a channel's RMSE changed by more than this factor.
REWEIGHT_RATIO = 1.5


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine`: the polished parameters and their evaluation."""

    theta: np.ndarray
    evaluation: Evaluation
    start: Evaluation
    simulations: int
    passes: int
    improved: bool


class WeightedResiduals:
    """Re-weighted residuals (:func:`~.objective.residual_vector`) and their Jacobian in the
    active entries of ``z = ln(theta)`` (the others stay at ``z_fixed``), with a cache so
    that the Jacobian at a point reuses the evaluation there."""

    def __init__(self, model: DryerModel, segments: Sequence[Segment], spec: ObjectiveSpec,
                 scale: np.ndarray, z_fixed: np.ndarray, active: np.ndarray) -> None:
        self.model = model
        self.segments = list(segments)
        self.spec = spec
        self.scale = scale
        self.z_fixed = np.asarray(z_fixed, float)
        self.active = np.asarray(active, bool)
        self.simulations = 0
        self._cache: dict[bytes, np.ndarray] = {}

    def full(self, za: np.ndarray) -> np.ndarray:
        """Active entries ``za`` (..., n_active) -> full ``z`` (..., 7)."""
        za = np.asarray(za, float)
        z = np.broadcast_to(self.z_fixed, za.shape[:-1] + (self.z_fixed.size,)).copy()
        z[..., self.active] = za
        return z

    def run(self, Za: np.ndarray) -> np.ndarray:
        """Residual vectors (B, n) at active entries ``Za``; NaN rows where the model
        failed."""
        Z = self.full(np.atleast_2d(Za))
        evs = evaluate_parameters(self.model, self.segments, np.exp(Z), self.spec)
        self.simulations += Z.shape[0]
        rows = []
        for z, ev in zip(Z, evs, strict=True):
            e = residual_vector(ev, np.exp(z), self.spec, self.scale)
            rows.append(e if np.all(np.isfinite(e)) else np.full(e.shape, np.nan))
        return np.vstack(rows)

    def fun(self, za: np.ndarray) -> np.ndarray:
        key = np.asarray(za, float).tobytes()
        if key not in self._cache:
            e = self.run(za)[0]
            # a failed solve: a residual far above any real one, so the step is refused
            self._cache = {key: np.where(np.isfinite(e), e, FAILED_RESIDUAL)}
        return self._cache[key]

    def jac(self, za: np.ndarray) -> np.ndarray:
        """Forward differences; a column whose forward member fails uses the backward
        difference, and is zero when both fail (the parameter cannot move there)."""
        za = np.asarray(za, float)
        e0 = self.fun(za)
        E = self.run(za[None, :] + FD_STEP * np.eye(za.size))
        J = (E - e0[None, :]) / FD_STEP
        bad = np.flatnonzero(np.isnan(E).any(axis=1))
        if bad.size:
            Eb = self.run(za[None, :] - FD_STEP * np.eye(za.size)[bad])
            J[bad] = (e0[None, :] - Eb) / FD_STEP
            J[np.isnan(J).any(axis=1)] = 0.0
        return J.T


def _rmse_ratio(a: float, b: float) -> float:
    """max(a/b, b/a) for positive finite RMSEs (1 otherwise)."""
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0 or b <= 0:
        return 1.0
    return max(a / b, b / a)


def refine(model: DryerModel, segments: Sequence[Segment], theta0: np.ndarray,
           bounds: np.ndarray, spec: ObjectiveSpec, *, passes: int = 2,
           max_nfev: int = 6) -> Refinement:
    """Polish ``theta0`` (7,) within ``bounds`` (7, 2) to lower the objective on ``segments``.

    At most ``passes`` re-weighting passes of at most ``max_nfev`` residual evaluations each
    (a further pass only when a channel's RMSE moved by more than :data:`REWEIGHT_RATIO`,
    i.e. when the weights of the last pass no longer hold). A first Jacobian over all seven
    parameters picks the *active* ones: those whose weighted sensitivity column is at least
    :data:`ACTIVE_FRACTION` of the largest; the others keep their value, and every later
    Jacobian costs one batched call of ``n_active`` simulations.
    """
    lo, hi = np.log(bounds[:, 0]), np.log(bounds[:, 1])
    z = np.clip(np.log(np.asarray(theta0, float)), lo, hi)
    start = evaluate_parameters(model, segments, np.exp(z), spec)[0]
    best_z, best, sims = z, start, 1
    all_on = np.ones(z.size, dtype=bool)
    done = 0
    active = all_on
    for p in range(int(passes)):
        if best.failed:
            break
        scale = irls_scale(best, spec)
        if p == 0:
            probe = WeightedResiduals(model, segments, spec, scale, best_z, all_on)
            e_start = residual_vector(best, np.exp(best_z), spec, scale)
            probe._cache = {best_z.tobytes(): e_start}
            norms = np.linalg.norm(probe.jac(best_z), axis=0)
            sims += probe.simulations
            active = norms >= ACTIVE_FRACTION * norms.max()
            if not active.any():
                break
        prob = WeightedResiduals(model, segments, spec, scale, best_z, active)
        prob._cache = {best_z[active].tobytes():
                       residual_vector(best, np.exp(best_z), spec, scale)}
        sol = least_squares(prob.fun, best_z[active], jac=prob.jac,
                            bounds=(lo[active], hi[active]), method="trf", x_scale=1.0,
                            max_nfev=max_nfev, xtol=1e-4, ftol=1e-4)
        sims += prob.simulations
        done += 1
        z_new = prob.full(np.clip(sol.x, lo[active], hi[active]))
        ev = evaluate_parameters(model, segments, np.exp(z_new), spec)[0]
        sims += 1
        if not ev.objective < best.objective:
            break
        moved = max(_rmse_ratio(ev.fit.rmse[n], best.fit.rmse[n]) for n in ev.fit.rmse)
        best_z, best = z_new, ev
        if moved < REWEIGHT_RATIO:
            break  # the weights of this pass still hold: a re-weighted pass gains nothing
    return Refinement(theta=np.exp(best_z), evaluation=best, start=start, simulations=sims,
                      passes=done, improved=best.objective < start.objective)


__all__ = ["FD_STEP", "Refinement", "WeightedResiduals", "refine"]
