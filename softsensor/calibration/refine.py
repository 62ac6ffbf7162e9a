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
    """Outcome of :func:`refine`: the polished parameters and their evaluation;
    ``simulations`` of parameter sets with the model, ``jac_simulations`` with the
    Jacobian's cheaper model."""

    theta: np.ndarray
    evaluation: Evaluation
    start: Evaluation
    simulations: int
    passes: int
    improved: bool
    jac_simulations: int = 0


class WeightedResiduals:
    """Re-weighted residuals (:func:`~.objective.residual_vector`) and their Jacobian in the
    active entries of ``z = ln(theta)`` (the others stay at ``z_fixed``), with a cache so
    that the Jacobian at a point reuses the evaluation there and a Jacobian asked twice at
    the same point is computed once.

    ``jac_model``: the model whose forward differences give the Jacobian (default ``model``).
    A cheaper one (the search's, with fewer wall substeps:
    :func:`~.calibration_run.search_model`) differs from ``model`` by far less than a step moves
    the outputs, so its differences steer the steps as well, while every residual the steps
    are accepted on is ``model``'s. Its base point runs in the same batched call as the
    displaced ones.
    """

    def __init__(self, model: DryerModel, segments: Sequence[Segment], spec: ObjectiveSpec,
                 scale: np.ndarray, z_fixed: np.ndarray, active: np.ndarray,
                 jac_model: DryerModel | None = None) -> None:
        self.model = model
        self.jac_model = None if jac_model is model else jac_model
        self.segments = list(segments)
        self.spec = spec
        self.scale = scale
        self.z_fixed = np.asarray(z_fixed, float)
        self.active = np.asarray(active, bool)
        self.simulations = 0
        self.jac_simulations = 0
        self._cache: dict[bytes, np.ndarray] = {}
        self._jac_cache: dict[bytes, np.ndarray] = {}
        self._evaluations: dict[bytes, Evaluation] = {}

    def full(self, za: np.ndarray) -> np.ndarray:
        """Active entries ``za`` (..., n_active) -> full ``z`` (..., 7)."""
        za = np.asarray(za, float)
        z = np.broadcast_to(self.z_fixed, za.shape[:-1] + (self.z_fixed.size,)).copy()
        z[..., self.active] = za
        return z

    def run(self, Za: np.ndarray, model: DryerModel | None = None
            ) -> tuple[np.ndarray, list[Evaluation]]:
        """Residual vectors (B, n) at active entries ``Za`` with ``model`` (default the
        residuals' own), NaN rows where the model failed, and the evaluations."""
        Z = self.full(np.atleast_2d(Za))
        evs = evaluate_parameters(model or self.model, self.segments, np.exp(Z), self.spec)
        if model is None:
            self.simulations += Z.shape[0]
        else:
            self.jac_simulations += Z.shape[0]
        rows = []
        for z, ev in zip(Z, evs, strict=True):
            e = residual_vector(ev, np.exp(z), self.spec, self.scale)
            rows.append(e if np.all(np.isfinite(e)) else np.full(e.shape, np.nan))
        return np.vstack(rows), evs

    def fun(self, za: np.ndarray) -> np.ndarray:
        key = np.asarray(za, float).tobytes()
        if key not in self._cache:
            E, evs = self.run(za)
            self._evaluations[key] = evs[0]
            # a failed solve: a residual far above any real one, so the step is refused
            self._cache = {key: np.where(np.isfinite(E[0]), E[0], FAILED_RESIDUAL)}
        return self._cache[key]

    def evaluation(self, za: np.ndarray) -> Evaluation | None:
        """The model's evaluation at ``za`` if :meth:`fun` simulated it (else None)."""
        return self._evaluations.get(np.asarray(za, float).tobytes())

    def seed(self, za: np.ndarray, ev: Evaluation, J: np.ndarray | None = None) -> None:
        """The evaluation ``ev`` (and the Jacobian ``J``, (n, n_active)) known at ``za``."""
        key = np.asarray(za, float).tobytes()
        e = residual_vector(ev, np.exp(self.full(za)), self.spec, self.scale)
        self._cache = {key: np.where(np.isfinite(e), e, FAILED_RESIDUAL)}
        self._evaluations[key] = ev
        if J is not None:
            self._jac_cache = {key: J}

    def jac(self, za: np.ndarray) -> np.ndarray:
        """Forward differences (n, n_active); a column whose forward member fails uses the
        backward difference, and is zero when both fail (the parameter cannot move there)."""
        za = np.asarray(za, float)
        key = za.tobytes()
        if key not in self._jac_cache:
            steps = FD_STEP * np.eye(za.size)
            model = None
            if self.jac_model is not None:
                E = self.run(np.vstack([za, za[None, :] + steps]), self.jac_model)[0]
                e0, E, model = E[0], E[1:], self.jac_model
            if model is None or np.isnan(e0).any():  # no cheaper model, or it failed here
                e0, model = self.fun(za), None
                E = self.run(za[None, :] + steps)[0]
            J = (E - e0[None, :]) / FD_STEP
            bad = np.flatnonzero(np.isnan(E).any(axis=1))
            if bad.size:
                Eb = self.run(za[None, :] - steps[bad], model)[0]
                J[bad] = (e0[None, :] - Eb) / FD_STEP
                J[np.isnan(J).any(axis=1)] = 0.0
            self._jac_cache = {key: J.T}
        return self._jac_cache[key]

    def jacobian_at(self, za: np.ndarray) -> np.ndarray | None:
        """The Jacobian last computed, if it was at ``za`` (else None)."""
        return self._jac_cache.get(np.asarray(za, float).tobytes())


class BroydenResiduals(WeightedResiduals):
    """:class:`WeightedResiduals` whose Jacobian is differenced once, at the first point it is
    asked (or seeded there), and then carried by Broyden's rank-one update
    ``J + (e - e_0 - J dx) dx' / (dx' dx)`` from the residuals at the points where it is
    asked next (the steps :func:`~scipy.optimize.least_squares` accepted, whose residuals it
    has already evaluated): a Gauss-Newton step costs one simulation instead of one per
    active parameter more (Dennis and Schnabel, *Numerical Methods for Unconstrained
    Optimization*, 1983, section 8.1). For a polish that starts close to its optimum."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def jac(self, za: np.ndarray) -> np.ndarray:
        za = np.asarray(za, float)
        key = za.tobytes()
        if key not in self._jac_cache and self._last is not None:
            x0, e0, J0 = self._last
            dx = za - x0
            if float(dx @ dx) > 0.0:
                e = self.fun(za)
                self._jac_cache = {key: J0 + np.outer(e - e0 - J0 @ dx, dx) / float(dx @ dx)}
        J = super().jac(za)
        self._last = (za.copy(), self.fun(za).copy(), J)
        return J


def row_channels(ev: Evaluation, n_rows: int) -> np.ndarray:
    """Channel (0, 1, 2) of each data row of :func:`~.objective.residual_vector` at ``ev``
    and -1 for its prior rows, which the re-weighting does not scale."""
    parts = [np.full(r[c].size, c) for r in ev.res for c in range(3)]
    data = np.concatenate(parts) if parts else np.zeros(0, int)
    return np.concatenate([data, np.full(n_rows - data.size, -1)]).astype(int)


def _rmse_ratio(a: float, b: float) -> float:
    """max(a/b, b/a) for positive finite RMSEs (1 otherwise)."""
    if not (np.isfinite(a) and np.isfinite(b)) or a <= 0 or b <= 0:
        return 1.0
    return max(a / b, b / a)


def _next_jacobian(prob: WeightedResiduals, x: np.ndarray, ev: Evaluation,
                   spec: ObjectiveSpec) -> np.ndarray | None:
    """The Jacobian ``prob`` last computed, if at ``x``, re-weighted to the scale of the
    next pass at ``ev`` (the prior's rows, channel -1, unchanged); else None."""
    J = prob.jacobian_at(x)
    if J is None:
        return None
    z = prob.full(x)
    channels = row_channels(ev, residual_vector(ev, np.exp(z), spec, prob.scale).size)
    ratio = irls_scale(ev, spec) / prob.scale
    return J * np.where(channels >= 0, ratio[np.maximum(channels, 0)], 1.0)[:, None]


def _active(model: DryerModel, segments: Sequence[Segment], spec: ObjectiveSpec,
            z: np.ndarray, ev: Evaluation, jac_model: DryerModel | None
            ) -> tuple[np.ndarray, np.ndarray, WeightedResiduals]:
    """The parameters the polish moves (:data:`ACTIVE_FRACTION`), the Jacobian's columns of
    them at ``z`` and the probe that computed it (its simulation counts)."""
    probe = WeightedResiduals(model, segments, spec, irls_scale(ev, spec), z,
                              np.ones(z.size, dtype=bool), jac_model)
    probe.seed(z, ev)
    J = probe.jac(z)
    norms = np.linalg.norm(J, axis=0)
    active = norms >= ACTIVE_FRACTION * norms.max() if norms.max() > 0 else norms > 0
    return active, J[:, active], probe


def refine(model: DryerModel, segments: Sequence[Segment], theta0: np.ndarray,
           bounds: np.ndarray, spec: ObjectiveSpec, *, passes: int = 2,
           max_nfev: int = 6, jac_model: DryerModel | None = None,
           broyden: bool = False) -> Refinement:
    """Polish ``theta0`` (7,) within ``bounds`` (7, 2) to lower the objective on ``segments``.

    At most ``passes`` re-weighting passes of at most ``max_nfev`` residual evaluations each
    (a further pass only when a channel's RMSE moved by more than :data:`REWEIGHT_RATIO`,
    i.e. when the weights of the last pass no longer hold). A first Jacobian over all seven
    parameters picks the *active* ones: those whose weighted sensitivity column is at least
    :data:`ACTIVE_FRACTION` of the largest; the others keep their value, and every later
    Jacobian costs one batched call of ``n_active`` simulations. Jacobians come from
    ``jac_model``'s differences when given (:class:`WeightedResiduals`); the first one
    starts the first pass, and the last one of a pass, re-weighted, the next. ``broyden``:
    within a pass, the Jacobian is updated from the residuals of the accepted steps
    (:class:`BroydenResiduals`) instead of differenced again at each.
    """
    lo, hi = np.log(bounds[:, 0]), np.log(bounds[:, 1])
    z = np.clip(np.log(np.asarray(theta0, float)), lo, hi)
    start = evaluate_parameters(model, segments, np.exp(z), spec)[0]
    best_z, best, sims, jac_sims, done = z, start, 1, 0, 0
    if start.failed:
        return Refinement(np.exp(z), start, start, sims, 0, False)
    active, J0, probe = _active(model, segments, spec, z, start, jac_model)
    sims, jac_sims = sims + probe.simulations, probe.jac_simulations
    for _ in range(int(passes) if active.any() else 0):
        kind = BroydenResiduals if broyden else WeightedResiduals
        prob = kind(model, segments, spec, irls_scale(best, spec), best_z, active, jac_model)
        prob.seed(best_z[active], best, J0)
        sol = least_squares(prob.fun, best_z[active], jac=prob.jac,
                            bounds=(lo[active], hi[active]), method="trf", x_scale=1.0,
                            max_nfev=max_nfev, xtol=1e-4, ftol=1e-4)
        done += 1
        x = np.clip(sol.x, lo[active], hi[active])
        ev = prob.evaluation(x)
        if ev is None:  # not where least_squares evaluated (it ends on an evaluated point)
            ev = evaluate_parameters(model, segments, np.exp(prob.full(x)), spec)[0]
            sims += 1
        sims, jac_sims = sims + prob.simulations, jac_sims + prob.jac_simulations
        if not ev.objective < best.objective:
            break
        moved = max(_rmse_ratio(ev.fit.rmse[n], best.fit.rmse[n]) for n in ev.fit.rmse)
        best_z, best, J0 = prob.full(x), ev, _next_jacobian(prob, x, ev, spec)
        if moved < REWEIGHT_RATIO:
            break  # the weights of this pass still hold: a re-weighted pass gains nothing
    return Refinement(theta=np.exp(best_z), evaluation=best, start=start, simulations=sims,
                      passes=done, improved=best.objective < start.objective,
                      jac_simulations=jac_sims)


__all__ = ["FD_STEP", "BroydenResiduals", "Refinement", "WeightedResiduals", "refine",
           "row_channels"]
