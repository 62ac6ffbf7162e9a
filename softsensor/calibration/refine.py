"""Local polish of the best TPE trial: bounded Gauss-Newton in log-parameter space.

TPE (paper section 3.3) finds the basin but converges slowly inside it: on a virtual-plant
day with known parameters, 200 TPE trials alone stop at about twice the cost at the true
values, with multipliers off by tens of percent along the ridge that ``mult_D`` and ``mult_h``
share. A few trust-region Gauss-Newton steps from the best trial close that gap.

Eq. 4, ``J = sum_m WF_m RMSE_m``, is not a sum of squares; it is minimised by iteratively
re-weighted least squares: with the RMSEs ``r_m`` of the current point, the residual vector

    e = [ sqrt(WF_m / (r_m N_m)) * (y_real,m,k - y_model,m,k) ]_{m,k}

has ``|e|^2 / 2 = sum_m WF_m MSE_m / (2 r_m)``, whose gradient equals that of ``J`` at the
current point. Each pass minimises ``|e|^2`` with :func:`scipy.optimize.least_squares`
(trust-region reflective, so Table 1 bounds are never left) over ``z = ln(theta)``; the
weights are refreshed between passes. The Jacobian comes from forward differences in ``z``
through one batched model call. The result is accepted only if it lowers ``J``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from softsensor.calibration.chunked_run import simulate_segments
from softsensor.calibration.cost import Fit, ModelRun, evaluate_fit, residuals
from softsensor.calibration.dataset import Segment
from softsensor.model import DryerModel

#: Forward-difference step in ln(theta).
FD_STEP = 1e-3
#: Residual entry standing for a failed model solve.
FAILED_RESIDUAL = 1e6
#: RMSE floors that keep the re-weighting finite on a perfect fit: 0.01 K, 1e-4 kg/kg.
RMSE_FLOOR = np.array([0.01, 0.01, 1e-4])
#: A parameter is polished when its weighted sensitivity column norm is at least this
#: fraction of the largest one.
ACTIVE_FRACTION = 1e-3
#: Another re-weighted pass runs only when a channel's RMSE changed by more than this factor.
REWEIGHT_RATIO = 1.5


@dataclass(frozen=True)
class Refinement:
    """Outcome of :func:`refine`: the polished parameters and their fit."""

    theta: np.ndarray
    fit: Fit
    start_fit: Fit
    simulations: int
    passes: int
    improved: bool


class WeightedResiduals:
    """Weighted residuals and their Jacobian in the active entries of ``z = ln(theta)`` (the
    others stay at ``z_fixed``), with a cache so that the Jacobian at a point reuses the
    residual simulation there."""

    def __init__(self, model: DryerModel, segments: Sequence[Segment], scale: np.ndarray,
                 z_fixed: np.ndarray, active: np.ndarray) -> None:
        self.model = model
        self.segments = list(segments)
        self.scale = scale  # per channel: sqrt(WF_m / (r_m N_m))
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

    def _vector(self, runs: list[ModelRun]) -> np.ndarray:
        """Stacked weighted residuals of a batch of runs (one per segment) -> (B, n)."""
        parts = []
        for run, seg in zip(runs, self.segments, strict=True):
            res = residuals(run, seg)
            parts += [self.scale[c] * res[c] for c in range(3)]
        return np.concatenate(parts, axis=-1)

    def run(self, Za: np.ndarray) -> np.ndarray:
        """Weighted residuals (B, n) at active entries ``Za``; NaN rows where the model
        failed."""
        Z = self.full(np.atleast_2d(Za))
        runs = simulate_segments(self.model, self.segments, np.exp(Z))
        self.simulations += Z.shape[0]
        E = self._vector(runs)
        E[~np.isfinite(E).all(axis=1)] = np.nan
        return E

    def fun(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if key not in self._cache:
            e = self.run(z)[0]
            # a failed solve: a residual far above any real one, so the step is refused
            self._cache = {key: np.where(np.isfinite(e), e, FAILED_RESIDUAL)}
        return self._cache[key]

    def jac(self, z: np.ndarray) -> np.ndarray:
        """Forward differences; a column whose forward member fails uses the backward
        difference, and is zero when both fail (the parameter cannot move there)."""
        e0 = self.fun(z)
        E = self.run(z[None, :] + FD_STEP * np.eye(z.size))
        J = (E - e0[None, :]) / FD_STEP
        bad = np.flatnonzero(np.isnan(E).any(axis=1))
        if bad.size:
            Eb = self.run(z[None, :] - FD_STEP * np.eye(z.size)[bad])
            J[bad] = (e0[None, :] - Eb) / FD_STEP
            J[np.isnan(J).any(axis=1)] = 0.0
        return J.T


def _rmse_ratio(a: float, b: float) -> float:
    """max(a/b, b/a) for positive finite RMSEs (1 otherwise)."""
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0 or b <= 0:
        return 1.0
    return max(a / b, b / a)


def irls_scale(fit: Fit, weights: np.ndarray, floor: np.ndarray = RMSE_FLOOR) -> np.ndarray:
    """Per-channel residual scale ``sqrt(WF_m / (RMSE_m N_m))`` of the re-weighted problem
    at ``fit`` (module docstring), RMSEs floored at ``floor``."""
    out = []
    for c, name in enumerate(fit.rmse):
        n = max(fit.n[name], 1)
        r = max(float(fit.rmse[name]) if np.isfinite(fit.rmse[name]) else 0.0, floor[c])
        out.append(np.sqrt(weights[c] / (r * n)))
    return np.array(out)


def refine(model: DryerModel, segments: Sequence[Segment], theta0: np.ndarray,
           bounds: np.ndarray, weights: np.ndarray, *, passes: int = 2,
           max_nfev: int = 6) -> Refinement:
    """Polish ``theta0`` (7,) within ``bounds`` (7, 2) to lower eq. 4 on ``segments``.

    At most ``passes`` re-weighting passes of at most ``max_nfev`` residual evaluations each
    (a further pass only when a channel's RMSE moved by more than :data:`REWEIGHT_RATIO`,
    i.e. when the weights of the last pass no longer hold). A first
    Jacobian over all seven parameters picks the *active* ones: those whose weighted
    sensitivity column is at least :data:`ACTIVE_FRACTION` of the largest; the others (no
    visible effect on the data at this point, e.g. ``mult_k``) keep their value, and every
    later Jacobian costs one batched call of ``n_active`` simulations.
    """
    weights = np.asarray(weights, float)
    lo, hi = np.log(bounds[:, 0]), np.log(bounds[:, 1])
    z = np.clip(np.log(np.asarray(theta0, float)), lo, hi)
    Y_start = simulate_segments(model, segments, np.exp(z)[None])
    start = evaluate_fit(Y_start, segments, weights)[0]
    floor = RMSE_FLOOR
    best_z, best_fit, sims = z, start, 1
    all_on = np.ones(z.size, dtype=bool)
    done = 0
    for p in range(int(passes)):
        scale = irls_scale(best_fit, weights, floor)
        if p == 0:
            probe = WeightedResiduals(model, segments, scale, best_z, all_on)
            e_start = probe._vector(Y_start)[0]
            probe._cache = {best_z.tobytes(): np.where(np.isfinite(e_start), e_start,
                                                       FAILED_RESIDUAL)}
            norms = np.linalg.norm(probe.jac(best_z), axis=0)
            sims += probe.simulations
            active = norms >= ACTIVE_FRACTION * norms.max()
            if not active.any():
                break
        prob = WeightedResiduals(model, segments, scale, best_z, active)
        if p == 0:
            prob._cache = {best_z[active].tobytes(): probe.fun(best_z)}
        sol = least_squares(prob.fun, best_z[active], jac=prob.jac,
                            bounds=(lo[active], hi[active]), method="trf", x_scale=1.0,
                            max_nfev=max_nfev, xtol=1e-4, ftol=1e-4)
        sims += prob.simulations
        done += 1
        z_new = prob.full(np.clip(sol.x, lo[active], hi[active]))
        fit = evaluate_fit(simulate_segments(model, segments, np.exp(z_new)[None]), segments,
                           weights)[0]
        sims += 1
        if not fit.cost < best_fit.cost:
            break
        moved = max(_rmse_ratio(fit.rmse[n], best_fit.rmse[n]) for n in fit.rmse)
        best_z, best_fit = z_new, fit
        if moved < REWEIGHT_RATIO:
            break  # the weights of this pass still hold: a re-weighted pass gains nothing
    return Refinement(theta=np.exp(best_z), fit=best_fit, start_fit=start, simulations=sims,
                      passes=done, improved=best_fit.cost < start.cost)


__all__ = ["FD_STEP", "Refinement", "WeightedResiduals", "irls_scale", "refine"]
