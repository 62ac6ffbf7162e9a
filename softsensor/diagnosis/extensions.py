"""Model extensions, one per cause of CONTRACT section 5, each fitted on the fit part of a day.

Every extension is a real change of the model through its public API
(:class:`~softsensor.model.DryerModel`) with one fitted parameter, fitted by weighted least
squares (:meth:`Problem.chi2 <softsensor.diagnosis.problem.Problem.chi2>`) on the fit part
only, then run over the whole day so that the held-out part scores it honestly:

================== ===========================================================================
cause              extension (fitted parameter)
================== ===========================================================================
sensor_bias        ``y_c + b`` on one outlet temperature ``c``, the better of the two; ``b``
                   [K] is the fit-part mean residual (closed form)
lab_delay          the lab sample times moved by ``delta`` [min] before the model is aligned
                   to them (grid search, 0.5 min steps within +-90 min; the temperatures are
                   untouched)
fouling_drift      ``mult_D`` and ``mult_h`` of every window scaled by ``1 - d t / T`` (``t``
                   from the start, ``T`` the day's length; per-window ``theta`` (K, 7));
                   ``d`` [-] is the loss by the end of the day
input_lag          the ``T_air_in`` the model sees is the measured one with a first-order
                   sensor lag of time constant ``tau`` [min] undone at scan resolution: over a
                   window, ``mean(x + tau dx/dt) = mean(x) + tau (x_end - x_start) / W``
                   (:attr:`~.windows.DayWindows.air_edges`)
ambient_heat_loss  outside heat loss scaled by ``1 + beta (283.15 K - T_amb)``, ``beta``
                   [1/K] (model aux ``BETA_AMB``)
inlet_moisture     the inlet moisture as an estimated disturbance: the UKF of
                   :mod:`softsensor.estimation.ukf` on the two outlet temperatures (no lab
                   results), its random-walk intensity [kg/kg/sqrt(h)] chosen on the fit part;
                   the model is driven by the estimate *available at the start* of each
                   window (one-step-ahead prediction)
================== ===========================================================================

The continuous parameters are fitted by :func:`_fit_scalar` (Gauss-Newton with secant
updates: a handful of model runs of the fit part). The inlet-moisture extension is a state
estimator, not a fixed trajectory: a trajectory fitted on the fit part would say nothing about
the held-out part. Its prediction of window ``k`` uses the temperatures of the windows before
``k`` only and never a lab result, so its held-out residuals are as honest as the others'.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.stats import chi2 as chi2_dist

from softsensor.diagnosis.problem import Prediction, Problem
from softsensor.diagnosis.windows import DayWindows, lab_sse_by_shift
from softsensor.errors import SoftsensorError
from softsensor.estimation.base import Window
from softsensor.estimation.settings import estimator_settings
from softsensor.estimation.ukf import UkfEstimator
from softsensor.estimation.ukf import log as ukf_logger
from softsensor.model.dryer import parameter_index
from softsensor.model.geometry import BETA_AMB, N_AUX
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS

_T_AIR = INPUT_NAMES.index("T_air_in")
_M_IN = INPUT_NAMES.index("moisture_in")
_MULT_D = parameter_index("mult_D")
_MULT_H = parameter_index("mult_h")


@dataclass
class Fitted:
    """An extension fitted on the fit part and run over the whole day.

    Attributes
    ----------
    cause : str
        The cause the extension stands for.
    params : dict[str, float]
        Fitted parameters, SI or the unit in the name (``..._min``).
    n_params : int
        Number of fitted parameters (for the penalty of the verdict).
    prediction : Prediction
        Outputs over the whole day with the fitted parameters.
    fit_chi2 : float
        Fit objective on the fit part at the fitted parameters (baseline: ``Problem.chi2``).
    description : str
        The fitted extension in words.
    channel : str or None
        The affected sensor (sensor_bias only).
    """

    cause: str
    params: dict[str, float]
    n_params: int
    prediction: Prediction
    fit_chi2: float
    description: str
    channel: str | None = None


@contextlib.contextmanager
def _quiet(logger: logging.Logger):
    """Hold ``logger`` at WARNING: the filter's per-tick notes are not news in a diagnosis."""
    level = logger.level
    logger.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        logger.setLevel(level)


class Extension(ABC):
    """One model extension; :meth:`fit` uses the fit part of ``problem`` only."""

    cause: ClassVar[str]
    n_params: ClassVar[int] = 1

    @abstractmethod
    def fit(self, problem: Problem) -> Fitted:
        """Fit on ``problem.split``'s fit part; return the extension run over the whole day."""

    def fit_both(self, problem: Problem) -> tuple[Fitted, Fitted]:
        """The extension fitted on the fit part and, separately, on the held-out part (the
        two folds of the cross-fitting in :mod:`.verdict`)."""
        return self.fit(problem), self.fit(problem.reversed())


def _fit_scalar(problem: Problem, make: Callable[[float, int | None], Prediction],
                bounds: tuple[float, float], step: float, tol: float,
                max_runs: int = 10) -> tuple[float, float]:
    """Least squares in one bounded parameter ``x`` by Gauss-Newton with secant updates.

    ``make(x, k_end)`` returns the prediction of the first ``k_end`` windows; ``x = 0`` is the
    baseline model. The residual vector is the normalised fit-part residuals
    (:meth:`Problem.fit_residual_vector`). The slope ``J = dr/dx`` starts from a forward
    difference of size ``step`` and is refreshed from each accepted step (secant), so a
    fit costs a few model runs of the fit part (at most ``max_runs``); a step that does not
    lower the sum of squares is halved; a parameter value whose model run fails is treated
    as infinitely bad. Stops when a step is below ``tol``. Returns ``(x, chi2)``.
    """
    k = problem.split.sim_end(problem.windows.n_windows)
    lo, hi = bounds

    def vector(x: float) -> np.ndarray | None:
        try:
            r = problem.fit_residual_vector(make(float(x), k))
        except SoftsensorError:
            return None
        return r if np.all(np.isfinite(r)) else None

    x = 0.0
    r = problem.fit_residual_vector(problem.prediction(problem.baseline.Y[:k]))
    f = float(r @ r)
    h = step if hi >= step else -step
    r_h = vector(h)
    runs = 1
    if r_h is None:
        return x, f
    J = (r_h - r) / h
    if float(r_h @ r_h) < f:
        x, r, f = h, r_h, float(r_h @ r_h)
    while runs < max_runs:
        jj = float(J @ J)
        if jj <= 0.0:
            break
        dx = -float(J @ r) / jj
        x_new = float(np.clip(x + dx, lo, hi))
        dx = x_new - x
        accepted = False
        while abs(dx) >= tol and runs < max_runs:
            r_new = vector(x + dx)
            runs += 1
            if r_new is not None and float(r_new @ r_new) < f:
                J = (r_new - r) / dx
                x, r, f = x + dx, r_new, float(r_new @ r_new)
                accepted = True
                break
            dx *= 0.5
        if not accepted or abs(dx) < tol:
            break
    return x, f


class SensorOffset(Extension):
    """``sensor_bias``: a constant offset ``b`` [K] on one outlet temperature sensor."""

    cause = "sensor_bias"

    def fit(self, problem: Problem) -> Fitted:
        base = problem.baseline
        r = problem.residuals(base)
        best: Fitted | None = None
        for c, name in enumerate(KELVIN_CHANNELS):
            rc = r.T[problem.split.fit_windows, c]
            b = float(np.nanmean(rc)) if np.isfinite(rc).any() else 0.0
            Y = base.Y.copy()
            Y[:, c] += b
            pred = Prediction(Y, base.lab)
            chi = problem.chi2(pred)
            if best is None or chi < best.fit_chi2:
                best = Fitted(self.cause, {"offset_K": b}, self.n_params, pred, chi,
                              f"{name} reads {b:+.2f} K off the model (offset fitted as the "
                              f"fit-part mean residual)", channel=name)
        assert best is not None
        return best


class LabTimeShift(Extension):
    """``lab_delay``: the lab's stamped sample times are off; move them by ``delta``."""

    cause = "lab_delay"
    #: Shifts searched. [min]
    grid_min = np.arange(-90.0, 90.0 + 1e-9, 0.5)
    #: Smallest drop of the fit part's lab chi-square (squared residuals over the lab noise
    #: level) for which a shift is applied: the chi-square quantile of the verdict's
    #: significance level (0.001, one degree of freedom). A handful of lab results taken
    #: where the outlet moisture is flat do not pin a shift, and the grid's best then lands
    #: anywhere (a fold fitted on eight such results put 84.5 min on a 44 min delay); such a
    #: shift is noise and is not applied.
    min_chi2_drop = float(chi2_dist.isf(1e-3, 1))

    def fit(self, problem: Problem) -> Fitted:
        base = problem.baseline
        fit = problem.split.lab_fit
        if not fit.any():
            pred = base
            return Fitted(self.cause, {"shift_min": 0.0}, self.n_params, pred,
                          problem.chi2(pred), "no lab result in the fit part: shift not fitted")
        sse = lab_sse_by_shift(problem.windows, base.Y[:, 2], self.grid_min, fit)
        n_labs = int(fit.sum())
        i0 = int(np.argmin(np.abs(self.grid_min)))
        i = int(np.argmin(sse))
        drop = (sse[i0] - sse[i]) / problem.sigma[2] ** 2
        kept = ""
        if not drop >= self.min_chi2_drop:
            kept = (f"; the best shift, {self.grid_min[i]:+.1f} min, lowers the lab "
                    f"chi-square by only {drop:.1f} (needed: {self.min_chi2_drop:.1f}), so none "
                    f"is applied")
            i = i0
        delta = float(self.grid_min[i])
        pred = problem.prediction(base.Y, delta * 60e9)
        when = "later" if delta > 0 else "earlier"
        return Fitted(self.cause, {"shift_min": delta}, self.n_params, pred, problem.chi2(pred),
                      f"lab samples were taken {abs(delta):.1f} min {when} than stamped "
                      f"(fit-part lab RMSE {math.sqrt(sse[i0] / n_labs):.4f} -> "
                      f"{math.sqrt(sse[i] / n_labs):.4f} kg/kg{kept})")


class TransferDrift(Extension):
    """``fouling_drift``: ``mult_D`` and ``mult_h`` fall linearly, by ``d`` at the day's end."""

    cause = "fouling_drift"
    bounds = (-1.0, 0.9)

    def theta(self, problem: Problem, d: float) -> np.ndarray:
        """Per-window parameters (K, 7): the two tube multipliers times ``1 - d t / T``."""
        w = problem.windows
        t_mid = (np.arange(w.n_windows) + 0.5) / w.n_windows
        factor = np.maximum(1.0 - d * t_mid, 0.02)
        th = np.tile(problem.theta, (w.n_windows, 1))
        th[:, _MULT_D] *= factor
        th[:, _MULT_H] *= factor
        return th

    def fit(self, problem: Problem) -> Fitted:
        U = problem.windows.U

        def make(d: float, k_end: int | None) -> Prediction:
            return problem.predict(U, self.theta(problem, d), k_end=k_end)

        d, chi = _fit_scalar(problem, make, self.bounds, step=0.05, tol=2e-3)
        pred = make(d, None)
        trend = "lose" if d >= 0 else "gain"
        return Fitted(self.cause, {"loss_by_end": d}, self.n_params, pred, chi,
                      f"tube heat and mass transfer (mult_h, mult_D) {trend} {abs(d):.0%} "
                      f"linearly over the {problem.windows.hours[-1]:.0f} h record")


class AirSensorLag(Extension):
    """``input_lag``: the ``T_air_in`` sensor lags the air by a first-order ``tau``."""

    cause = "input_lag"
    bounds_min = (0.0, 45.0)

    def inputs(self, problem: Problem, tau_min: float) -> np.ndarray:
        """Window inputs with ``T_air_in`` de-lagged (module table). [K]"""
        w = problem.windows
        U = w.U.copy()
        U[:, _T_AIR] += tau_min * 60.0 * np.diff(w.air_edges) / w.window_s
        U[:, _T_AIR] = np.clip(U[:, _T_AIR], 300.0, 1000.0)
        return U

    def fit(self, problem: Problem) -> Fitted:
        def make(tau: float, k_end: int | None) -> Prediction:
            return problem.predict(self.inputs(problem, tau), k_end=k_end)

        tau, chi = _fit_scalar(problem, make, self.bounds_min, step=2.0, tol=0.05)
        return Fitted(self.cause, {"tau_min": tau}, self.n_params, make(tau, None), chi,
                      f"T_air_in sensor lags the air by a first-order time constant of "
                      f"{tau:.1f} min")


class AmbientHeatLoss(Extension):
    """``ambient_heat_loss``: outside heat loss grows by ``beta`` per K of ambient below
    283.15 K (model aux ``BETA_AMB``)."""

    cause = "ambient_heat_loss"
    bounds = (-0.1, 0.6)

    def fit(self, problem: Problem) -> Fitted:
        U = problem.windows.U

        def make(beta: float, k_end: int | None) -> Prediction:
            aux = np.zeros(N_AUX)
            aux[BETA_AMB] = beta
            return problem.predict(U, aux=aux, k_end=k_end)

        beta, chi = _fit_scalar(problem, make, self.bounds, step=0.02, tol=5e-4)
        return Fitted(self.cause, {"beta_amb_per_K": beta}, self.n_params, make(beta, None), chi,
                      f"outside heat loss scales by 1 {beta:+.3f}/K x (283.15 K - T_amb), "
                      f"i.e. {beta * 10:+.0%} per 10 K of cold")


class InletMoistureEstimate(Extension):
    """``inlet_moisture``: the inlet moisture as a disturbance tracked by the UKF."""

    cause = "inlet_moisture"
    #: Random-walk intensities tried on the fit part. [kg/kg / sqrt(h)]
    walks = (0.01, 0.04)

    def estimator(self, problem: Problem, walk: float) -> UkfEstimator:
        """A UKF on the calibrated model with random-walk intensity ``walk``."""
        cfg = problem.config
        settings = dataclasses.replace(estimator_settings(cfg), moisture_in_walk=walk)
        return UkfEstimator(cfg, settings, model=problem.model)

    def run(self, problem: Problem, ukf: UkfEstimator, k0: int, k1: int) -> np.ndarray:
        """Tick ``ukf`` over windows ``k0 .. k1-1`` with the outlet temperatures (no labs);
        return the posterior inlet moisture after each. [kg/kg]"""
        w = problem.windows
        out = np.empty(k1 - k0)
        with _quiet(ukf_logger):
            self._ticks(ukf, w, k0, k1, out)
        return out

    @staticmethod
    def _ticks(ukf: UkfEstimator, w: DayWindows, k0: int, k1: int, out: np.ndarray) -> None:
        for i, k in enumerate(range(k0, k1)):
            means: dict[str, float | None] = {n: float(w.U[k, j])
                                              for j, n in enumerate(INPUT_NAMES[:-1])}
            n_good = {n: int(w.n_scans[k]) for n in means}
            for c, n in enumerate(KELVIN_CHANNELS):
                v = w.Y[k, c]
                means[n] = float(v) if np.isfinite(v) else None
                n_good[n] = int(w.n_good_out[k, c])
            start = int(w.end_ns[k] - round(w.window_s * 1e9))
            body = ukf.tick(Window(start, int(w.end_ns[k]), means, int(w.n_scans[k]), n_good))
            out[i] = body["moisture_in"]

    def inputs(self, problem: Problem, m_hat: np.ndarray) -> np.ndarray:
        """Inputs with window ``k`` driven by the estimate after window ``k - 1``."""
        U = problem.windows.U[:len(m_hat)].copy()
        U[1:, _M_IN] = m_hat[:-1]
        return U

    def fit(self, problem: Problem) -> Fitted:
        return self._choose(problem, self._runs(problem))

    def fit_both(self, problem: Problem) -> tuple[Fitted, Fitted]:
        """Both folds from one filter run per intensity: the filter never reads a lab
        result and a run over the whole day holds the fit part of either fold."""
        runs = self._runs(problem)
        return self._choose(problem, runs), self._choose(problem.reversed(), runs)

    def _runs(self, problem: Problem) -> list[tuple[float, np.ndarray, Prediction]]:
        """For every intensity, the estimate over the whole day and the model it drives."""
        out = []
        for walk in self.walks:
            m_hat = self.run(problem, self.estimator(problem, walk), 0,
                             problem.windows.n_windows)
            try:
                out.append((walk, m_hat, problem.predict(self.inputs(problem, m_hat))))
            except SoftsensorError:
                continue
        if not out:
            raise SoftsensorError("inlet-moisture extension: the model failed for every "
                                  "random-walk intensity tried")
        return out

    def _choose(self, problem: Problem,
                runs: list[tuple[float, np.ndarray, Prediction]]) -> Fitted:
        """The intensity whose run fits ``problem``'s fit part best."""
        walk, m_hat, pred = min(runs, key=lambda r: problem.chi2(r[2]))
        return Fitted(self.cause, {"walk_per_sqrt_h": walk}, self.n_params, pred,
                      problem.chi2(pred),
                      f"inlet moisture tracked from the outlet temperatures (random walk "
                      f"{walk:g} kg/kg/sqrt(h)): {m_hat.min():.2f} to {m_hat.max():.2f} kg/kg "
                      f"over the day, mean {m_hat.mean():.2f}")


#: One extension per injectable cause, in CONTRACT order.
EXTENSIONS: tuple[Extension, ...] = (
    InletMoistureEstimate(), SensorOffset(), LabTimeShift(), TransferDrift(), AirSensorLag(),
    AmbientHeatLoss(),
)
