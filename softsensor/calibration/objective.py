"""What the calibration minimises: a cost of the residuals left after the inlet moisture is
fitted, plus a prior on the parameters.

For a batch of parameter sets, every segment is simulated twice: as it is (``base``) and with
the inlet moisture raised by :data:`~.disturbance.DELTA` (``sens``), which gives each compared
output's sensitivity to the unmeasured inlet moisture. With ``inlet`` estimated
(:mod:`.disturbance`) the best slow trajectory of it is fitted per segment in closed form and
the cost is measured on the residuals it leaves; with ``inlet`` nominal, on the raw residuals.

Data terms (``cost``), over the pooled samples of every segment:

* ``eq4``, the paper's eq. 4: ``J = sum_m WF_m RMSE_m``;
* ``likelihood``: the Gaussian negative log-likelihood with each channel's noise variance
  estimated from the data (profiled out: ``sigma_m^2 = MSE_m``), ``sum_m (N_eff,m / 2)
  ln MSE_m``, plus the trajectory's prior ``sum_s c_s' L c_s / 2``. ``N_eff,m = rho_m N_m``
  counts the temperature windows by their effective number: the model's error on them is
  serially correlated and carries less information than independent noise; ``rho_m`` is set
  once per calibration from the lag-one autocorrelation at the starting point
  (:func:`effective_ratio`). Under eq. 4 a 3 K temperature error costs less than
  0.002 kg/kg of moisture; under the likelihood each channel counts by its own noise.

Prior (the MAP fit): ``ln(theta) ~ N(ln(theta_config), prior_sigma^2)`` per parameter, its
negative log density ``P = sum_i (ln theta_i - ln theta_config,i)^2 / (2 prior_sigma^2)``
added as ``lambda P``. For the likelihood ``lambda = 1``. Eq. 4 is not a log-likelihood; near
its minimum a change of one sample's squared residual by one noise variance moves channel
``m``'s term by ``WF_m RMSE_m / (2 N_m)``, so eq. 4 behaves like a log-likelihood scaled by
that amount on the channel that dominates it (the lab moisture: few samples, large weight).
The prior enters eq. 4 as ``lambda = max_m WF_m RMSE_m / (2 N_m)`` at the config's values
(:func:`prior_scale`): one prior standard deviation costs what one noise-sized lab residual
does.

Refinement (:mod:`.refine`) needs the objective as a sum of squares near a point:
:func:`residual_vector` stacks the re-weighted residuals whose half squared norm has the
objective's gradient there (iteratively re-weighted least squares).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from softsensor.calibration.cost import Fit, ModelRun, fit_from_residuals, residuals
from softsensor.calibration.dataset import Segment
from softsensor.calibration.disturbance import DELTA, InletPrior, hat_basis, solve
from softsensor.signals import OUTPUT_NAMES

#: RMSE floors that keep logarithms and re-weighting finite on a perfect fit [K, K, kg/kg].
RMSE_FLOOR = np.array([0.01, 0.01, 1e-4])
#: Largest lag-one autocorrelation used for the effective sample size.
MAX_RHO = 0.95


@dataclass(frozen=True)
class ObjectiveSpec:
    """How a parameter set is scored (module docstring).

    Attributes
    ----------
    cost : str
        ``"eq4"`` or ``"likelihood"``.
    weights : ndarray (3,)
        Eq. 4 weights in :data:`~softsensor.signals.OUTPUT_NAMES` order.
    prior_center : ndarray (7,) or None
        ``ln(theta)`` the prior is centred on; None: no prior.
    prior_sigma : float
        Prior standard deviation of ``ln(theta)``.
    prior_scale : float
        ``lambda``, the prior's weight against the data term.
    inlet : InletPrior or None
        The inlet-moisture trajectory's prior; None: nominal inlet moisture.
    n_eff_ratio : ndarray (3,)
        ``N_eff / N`` per channel for the likelihood.
    inlet_from_labs : bool
        Fit the trajectory to the lab results too (calibration). False: to the temperatures
        only, so that the lab results score it out of sample (validation: what the virtual
        sensor does before a lab result arrives).
    """

    cost: str
    weights: np.ndarray
    prior_center: np.ndarray | None = None
    prior_sigma: float = 1.0
    prior_scale: float = 1.0
    inlet: InletPrior | None = None
    n_eff_ratio: np.ndarray = field(default_factory=lambda: np.ones(3))
    inlet_from_labs: bool = True

    def prior(self, theta: np.ndarray) -> np.ndarray:
        """``lambda P`` per member of ``theta`` (B, 7) (0 without a prior)."""
        theta = np.atleast_2d(theta)
        if self.prior_center is None:
            return np.zeros(theta.shape[0])
        z = (np.log(theta) - self.prior_center) / self.prior_sigma
        return self.prior_scale * 0.5 * np.sum(z * z, axis=1)


@dataclass
class Evaluation:
    """One parameter set scored on every segment.

    ``fit`` is eq. 4 and the RMSEs of the residuals the cost sees (after the inlet trajectory
    when it is estimated), ``open_fit`` those of the model with the nominal inlet moisture;
    ``inlet[s]`` the knot values of segment ``s``'s trajectory [kg/kg] (empty when nominal),
    ``knots[s]`` their times [h from the segment's start]; ``res[s][c]`` the residuals the cost
    sees and ``inlet_penalty`` the trajectories' prior ``sum c' L c / 2``.
    """

    fit: Fit
    open_fit: Fit
    data: float
    prior: float
    objective: float
    inlet: list[np.ndarray]
    knots: list[np.ndarray]
    res: list[list[np.ndarray]]
    inlet_penalty: float = 0.0

    @property
    def failed(self) -> bool:
        return not np.isfinite(self.objective)


def _hours_of(seg: Segment, k: int, n_lab: int) -> tuple[np.ndarray, np.ndarray]:
    """Window-end and lab times [h from the segment's start] of the first ``k`` windows."""
    t_win = (np.arange(1, k + 1) * seg.window) / 3600.0
    t_lab = (seg.lab_time_ns[:n_lab] - seg.start_ns) / 3.6e12
    return t_win, t_lab


def _corrected(seg: Segment, base: ModelRun, sens: ModelRun, b: int, k: int,
               prior: InletPrior, use_labs: bool = True
               ) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, float]:
    """Residuals of member ``b`` over the first ``k`` windows after the best inlet trajectory
    (:mod:`.disturbance`); returns ``(residuals per channel, knot values, knot times,
    c' L c / 2)``."""
    n_lab = seg.labs_before(k)
    t_win, t_lab = _hours_of(seg, k, n_lab)
    knots = prior.knots(k * seg.window / 3600.0)
    L = prior.precision(knots)
    B_win, B_lab = hat_basis(t_win, knots), hat_basis(t_lab, knots)
    rows, parts = [], []
    for c in range(2):
        meas = seg.Y[:k, c]
        ok = np.isfinite(meas)
        r = meas[ok] - base.Y[b, :k, c][ok]
        s = (sens.Y[b, :k, c][ok] - base.Y[b, :k, c][ok]) / DELTA
        rows.append((r, s, B_win[ok]))
    r = seg.lab_value[:n_lab] - base.lab[b, :n_lab]
    s = (sens.lab[b, :n_lab] - base.lab[b, :n_lab]) / DELTA
    rows.append((r, s, B_lab))
    if not all(np.all(np.isfinite(x[0])) and np.all(np.isfinite(x[1])) for x in rows):
        return [x[0] for x in rows], np.full(len(knots), np.nan), knots, np.nan
    var = np.array([max(float(np.mean(x[0] ** 2)) if x[0].size else 0.0, RMSE_FLOOR[c] ** 2)
                    for c, x in enumerate(rows)])
    c_hat = np.zeros(len(knots))
    fitted = rows if use_labs else rows[:2]
    for _ in range(2):  # weights from the residuals the trajectory leaves (EM-like)
        c_hat = solve([(r, s, B, 1.0 / v) for (r, s, B), v in zip(fitted, var, strict=False)],
                      L)
        parts = [r - s * (B @ c_hat) for r, s, B in rows]
        var = np.array([max(float(np.mean(p**2)) if p.size else 0.0, RMSE_FLOOR[c] ** 2)
                        for c, p in enumerate(parts)])
    return parts, c_hat, knots, float(0.5 * c_hat @ L @ c_hat)


def inlet_fitted_run(seg: Segment, base: ModelRun, sens: ModelRun, c_hat: np.ndarray,
                     knots_h: np.ndarray) -> ModelRun:
    """Member 0 of ``base`` on ``seg`` with the inlet trajectory ``c_hat`` (knot values at
    ``knots_h`` [h]) added through the sensitivities ``(sens - base) / DELTA``: the model's
    outputs at every window end and lab sample as the cost compares them (measured minus these
    are the residuals it sees). Without a trajectory, ``base``'s member 0."""
    if c_hat.size == 0:
        return base.member(0)
    t_win, t_lab = _hours_of(seg, seg.n_windows, len(seg.lab_value))
    d_win = hat_basis(t_win, knots_h) @ c_hat
    d_lab = hat_basis(t_lab, knots_h) @ c_hat
    Y = base.Y[0] + (sens.Y[0] - base.Y[0]) / DELTA * d_win[:, None]
    lab = base.lab[0] + (sens.lab[0] - base.lab[0]) / DELTA * d_lab
    return ModelRun.single(Y, lab)


def _data_term(fit: Fit, spec: ObjectiveSpec, inlet_penalty: float) -> float:
    if not np.isfinite(fit.cost):
        return float("inf")
    if spec.cost == "eq4":
        return float(fit.cost)
    total = inlet_penalty
    for c, name in enumerate(OUTPUT_NAMES):
        n = fit.n[name]
        if n:
            mse = max(float(fit.rmse[name]) ** 2, RMSE_FLOOR[c] ** 2)
            total += 0.5 * spec.n_eff_ratio[c] * n * np.log(mse)
    return float(total)


def evaluate(segments: Sequence[Segment], base: Sequence[ModelRun],
             sens: Sequence[ModelRun] | None, theta: np.ndarray, spec: ObjectiveSpec,
             upto: Sequence[int] | None = None) -> list[Evaluation]:
    """Score every member of ``theta`` (B, 7) from its runs (one :class:`ModelRun` per
    segment; ``sens`` the inlet-raised runs, needed when ``spec.inlet`` is set).

    ``upto[s]`` limits segment ``s`` to its first windows (partial cost for pruning). A member
    whose model failed on any compared sample gets an infinite objective.
    """
    theta = np.atleast_2d(theta)
    B = theta.shape[0]
    ks = [seg.n_windows if upto is None else int(upto[s]) for s, seg in enumerate(segments)]
    raw = [residuals(run, seg, k) for run, seg, k in zip(base, segments, ks, strict=True)]
    open_fits = fit_from_residuals(raw, spec.weights)
    prior = spec.prior(theta)
    out = []
    for b in range(B):
        if spec.inlet is None:
            res_b = [[r[c][b] for c in range(3)] for r in raw]
            cs = [np.zeros(0) for _ in segments]
            knots = [np.zeros(0) for _ in segments]
            pen = 0.0
        else:
            if sens is None:
                raise ValueError("an estimated inlet moisture needs the inlet-raised runs")
            res_b, cs, knots, pen = [], [], [], 0.0
            for seg, run, srun, k in zip(segments, base, sens, ks, strict=True):
                parts, c_hat, kn, p = _corrected(seg, run, srun, b, k, spec.inlet,
                                                 spec.inlet_from_labs)
                res_b.append(parts)
                cs.append(c_hat)
                knots.append(kn)
                pen += p
        fit = fit_from_residuals([[p[None] for p in r] for r in res_b], spec.weights)[0]
        data = _data_term(fit, spec, pen) if np.isfinite(pen) else float("inf")
        obj = data + float(prior[b]) if np.isfinite(data) else float("inf")
        out.append(Evaluation(fit=fit, open_fit=open_fits[b], data=data, prior=float(prior[b]),
                              objective=obj, inlet=cs, knots=knots, res=res_b,
                              inlet_penalty=pen))
    return out


def irls_scale(ev: Evaluation, spec: ObjectiveSpec) -> np.ndarray:
    """Per-channel residual scale whose re-weighted half squared norm has the data term's
    gradient at ``ev`` (module docstring): eq. 4 ``sqrt(WF_m / (RMSE_m N_m))``, likelihood
    ``sqrt(rho_m / MSE_m)``."""
    out = np.empty(3)
    for c, name in enumerate(OUTPUT_NAMES):
        n = max(ev.fit.n[name], 1)
        r = float(ev.fit.rmse[name]) if np.isfinite(ev.fit.rmse[name]) else 0.0
        r = max(r, RMSE_FLOOR[c])
        out[c] = (np.sqrt(spec.weights[c] / (r * n)) if spec.cost == "eq4"
                  else np.sqrt(spec.n_eff_ratio[c]) / r)
    return out


def residual_vector(ev: Evaluation, theta: np.ndarray, spec: ObjectiveSpec,
                    scale: np.ndarray) -> np.ndarray:
    """Stacked re-weighted residuals: data (per channel times ``scale``), the trajectories'
    prior (likelihood), the parameters' prior; ``|e|^2 / 2`` has the objective's gradient at
    the point ``scale`` was taken."""
    parts = [scale[c] * r[c] for r in ev.res for c in range(3)]
    if spec.cost == "likelihood" and spec.inlet is not None:
        for c_hat, kn in zip(ev.inlet, ev.knots, strict=True):
            if c_hat.size:
                parts.append(np.linalg.cholesky(spec.inlet.precision(kn)).T @ c_hat)
    if spec.prior_center is not None:
        z = (np.log(np.asarray(theta, float)) - spec.prior_center) / spec.prior_sigma
        parts.append(np.sqrt(spec.prior_scale) * z)
    return np.concatenate(parts)


def effective_ratio(ev: Evaluation, segments: Sequence[Segment]) -> np.ndarray:
    """``N_eff / N = (1 - rho) / (1 + rho)`` per channel from the lag-one autocorrelation
    ``rho`` of the temperature residuals (windows in time order; labs: 1)."""
    out = np.ones(3)
    for c in range(2):
        rhos = []
        for r in ev.res:
            x = np.asarray(r[c], float)
            if x.size >= 3:
                d = x - x.mean()
                den = float(d @ d)
                if den > 0:
                    rhos.append(float(d[1:] @ d[:-1] / den))
        rho = float(np.clip(np.mean(rhos), 0.0, MAX_RHO)) if rhos else 0.0
        out[c] = (1.0 - rho) / (1.0 + rho)
    return out


def prior_scale(cost: str, ev_config: Evaluation, weights: np.ndarray) -> float:
    """``lambda`` of the prior (module docstring): 1 for the likelihood; for eq. 4 the largest
    ``WF_m RMSE_m / (2 N_m)`` over the channels at the config's values."""
    if cost != "eq4":
        return 1.0
    per = [weights[c] * ev_config.fit.rmse[n] / (2.0 * ev_config.fit.n[n])
           for c, n in enumerate(OUTPUT_NAMES)
           if ev_config.fit.n[n] and np.isfinite(ev_config.fit.rmse[n])]
    lam = max(per) if per else 0.0
    return float(lam) if lam > 0 else 1e-6


def sensitivity_offsets(B: int, with_inlet: bool) -> np.ndarray | None:
    """Per-member input offsets (2B, 8) for base and inlet-raised members, or None."""
    if not with_inlet:
        return None
    from softsensor.signals import INPUT_NAMES

    du = np.zeros((2 * B, len(INPUT_NAMES)))
    du[B:, INPUT_NAMES.index("moisture_in")] = DELTA
    return du


__all__ = [
    "Evaluation",
    "ObjectiveSpec",
    "effective_ratio",
    "evaluate",
    "irls_scale",
    "prior_scale",
    "residual_vector",
    "sensitivity_offsets",
    "inlet_fitted_run",
]
