"""Model extensions, one per cause of CONTRACT section 5, each fitted on the fit part of a day.

Every extension is a real change of the model through its public API
(:class:`~softsensor.model.DryerModel`) with one fitted parameter, fitted by weighted least
squares (:meth:`Problem.chi2 <softsensor.diagnosis.problem.Problem.chi2>`) on the fit part
only, then run over the whole day so that the held-out part scores it honestly:

================== ===========================================================================
cause              extension (fitted parameter)
================== ===========================================================================
sensor_bias        ``y_c + b`` on one outlet temperature ``c``, the better of the two; ``b``
                   [K] by generalised least squares (closed form: the whitening is linear)
lab_delay          the lab sample times moved by ``delta`` [min] before the model is aligned
                   to them (:mod:`softsensor.windows.lab_alignment`; grid search, 2 min
                   steps within +-90 min refined to 0.5 min; the temperatures are untouched)
fouling_drift      ``mult_D`` and ``mult_h`` falling as ``1 - d t / T`` (``t`` from the start,
                   ``T`` the day's length), the outputs moved quasi-statically by ``d t / T``
                   times the model's steady response to that loss; ``d`` [-] is the loss by
                   the end of the day
input_lag          the ``T_air_in`` the model sees is the measured one with a first-order
                   sensor lag of time constant ``tau`` [min] undone: over a window,
                   ``mean(x + tau dx/dt) = mean(x) + tau (x_end - x_start) / W``
                   (``air_edges`` of :class:`~.day_windows.DayWindows`), and in the sub-window
                   bins a lab sample sees (:func:`~.day_windows.delagged_air`)
ambient_heat_loss  outside heat loss scaled by ``1 + beta (283.15 K - T_amb)``, ``beta``
                   [1/K] (model aux ``BETA_AMB``)
inlet_moisture     the inlet moisture as an estimated disturbance: the UKF of
                   :mod:`softsensor.estimation.ukf` on the day's windows as the daemon hands
                   them over, without the lab results, its random-walk intensity
                   [kg/kg/sqrt(h)] chosen on the fit part; the model is driven by the
                   estimate *available at the start* of each window (one-step-ahead
                   prediction)
================== ===========================================================================

Every fit minimises the whitened fit-part residuals of :meth:`Problem.chi2
<softsensor.diagnosis.problem.Problem.chi2>`: what the calibration-error alternative
(:mod:`.calibration_error`) cannot predict. The continuous parameters are fitted by
:func:`_fit_scalar` (bounded :func:`scipy.optimize.least_squares`: a handful of model runs of
the fit part). The inlet-moisture extension is a state
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
from scipy.optimize import least_squares
from scipy.stats import chi2 as chi2_dist

from softsensor.calibration.dataset import LabPoints
from softsensor.diagnosis.day_windows import delagged_air
from softsensor.diagnosis.problem import Prediction, Problem
from softsensor.errors import SoftsensorError
from softsensor.estimation.settings import estimator_settings
from softsensor.estimation.ukf import UkfEstimator
from softsensor.estimation.ukf import log as ukf_logger
from softsensor.model.dryer import parameter_index
from softsensor.model.geometry import BETA_AMB, N_AUX
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS

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

    #: The size at which :meth:`probe` applies the cause, in :attr:`probe_unit`: the virtual
    #: plant's default size of the effect (a size plants see), a scale for the signature.
    probe_size: ClassVar[float] = 1.0
    probe_unit: ClassVar[str] = ""
    #: The sensor :meth:`probe` applies the cause to when no channel is given (None: the
    #: cause is not a sensor's).
    default_channel: ClassVar[str | None] = None

    @abstractmethod
    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        """The baseline with this cause applied at :attr:`probe_size` over the whole day (its
        signature on this day; ``channel`` picks the sensor of a sensor offset)."""


def _fit_scalar(problem: Problem, make: Callable[[float, int | None], Prediction],
                bounds: tuple[float, float], step: float, tol: float,
                max_runs: int = 10) -> tuple[float, float]:
    """Least squares in one bounded parameter ``x`` by :func:`scipy.optimize.least_squares`.

    ``make(x, k_end)`` returns the prediction of the first ``k_end`` windows; ``x = 0`` is the
    baseline model and the starting point (one ``step`` inside when it is a bound). The
    residual vector is the whitened fit-part residuals (:meth:`Problem.fit_residual_vector`).
    Trust-region reflective keeps ``x`` inside ``bounds``; the slope ``dr/dx`` is a forward
    difference of size ``step`` (towards the inside of the bounds), the unit in which the
    trust region is scaled. The search stops when a step is small beside ``x`` (``xtol =
    tol / (hi - lo)``), when the sum of squares falls by less than 1e-4 of itself, or after
    ``max_runs`` evaluations of the residuals. A value whose model run fails gets residuals
    far above the baseline's, so it is never accepted. Returns ``(x, chi2)``, never worse
    than the baseline's.
    """
    k = problem.split.sim_end(problem.windows.n_windows)
    lo, hi = bounds
    r0 = problem.fit_residual_vector(problem.baseline)
    f0 = float(r0 @ r0)
    # a failed run scores 100 times the baseline's sum of squares, spread over the residuals
    failed = np.full(r0.shape, 10.0 * math.sqrt(max(f0, 1.0) / max(r0.size, 1)))
    cache: dict[float, np.ndarray] = {0.0: r0}

    def residuals(x: float) -> np.ndarray:
        x = float(x)
        if x not in cache:
            try:
                r = problem.fit_residual_vector(make(x, k))
            except SoftsensorError:
                r = failed
            cache[x] = r if np.all(np.isfinite(r)) else failed
        return cache[x]

    def slope(z: np.ndarray) -> np.ndarray:
        x = float(z[0])
        h = step if x + step <= hi else -step
        return ((residuals(x + h) - residuals(x)) / h)[:, None]

    # trf starts strictly inside the bounds with a trust region of |x0| (in units of step),
    # or of one step from x0 = 0: a baseline on a bound starts one step inside instead
    x0 = lo + step if lo == 0.0 else hi - step if hi == 0.0 else 0.0
    sol = least_squares(lambda z: residuals(z[0]), [x0], jac=slope, bounds=([lo], [hi]),
                        method="trf", x_scale=[step], xtol=tol / max(hi - lo, tol),
                        ftol=1e-4, max_nfev=max_runs)
    x = float(np.clip(sol.x[0], lo, hi))
    r = residuals(x)
    f = float(r @ r)
    return (x, f) if f < f0 else (0.0, f0)


class SensorOffset(Extension):
    """``sensor_bias``: a constant offset ``b`` [K] on one outlet temperature sensor.

    The whitening of :mod:`.calibration_error` is linear, so the whitened fit-part residuals
    are ``v0 - b d`` with ``d`` the whitened unit offset: ``b = <v0, d> / <d, d>`` in closed
    form. The calibration-error alternative already carries each channel's own slowly
    varying offset with the size the calibration left; the extension wins where one channel
    reads off by more than that, and a shift both channels share stays with the
    alternative's common state."""

    cause = "sensor_bias"
    probe_size = 3.0
    probe_unit = "K"
    default_channel = KELVIN_CHANNELS[0]

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        unit = np.zeros(3)
        unit[KELVIN_CHANNELS.index(channel or self.default_channel)] = self.probe_size
        return _offset(problem.baseline, unit)

    def fit(self, problem: Problem) -> Fitted:
        base = problem.baseline
        v0 = problem.fit_residual_vector(base)
        best: Fitted | None = None
        for c, name in enumerate(KELVIN_CHANNELS):
            unit = np.zeros(3)
            unit[c] = 1.0
            d = v0 - problem.fit_residual_vector(_offset(base, unit))
            dd = float(d @ d)
            b = float(v0 @ d) / dd if dd > 0 else 0.0
            pred = _offset(base, b * unit)
            chi = problem.chi2(pred)
            if best is None or chi < best.fit_chi2:
                best = Fitted(self.cause, {"offset_K": b}, self.n_params, pred, chi,
                              f"{name} reads {b:+.2f} K off the model (offset fitted by "
                              f"generalised least squares on the fit part)", channel=name)
        assert best is not None
        return best


def _offset(pred: Prediction, offsets: np.ndarray) -> Prediction:
    """``pred`` with a constant offset (3,) on each output channel."""
    o = np.asarray(offsets, float)
    return Prediction(pred.Y + o, pred.lab + o[2])


class LabTimeShift(Extension):
    """``lab_delay``: the lab's stamped sample times are off; move them by ``delta``."""

    cause = "lab_delay"
    #: Coarse grid of shifts searched, then refined around its best. [min]
    grid_min = np.arange(-90.0, 90.0 + 1e-9, 2.0)
    #: Refinement around the coarse best. [min]
    refine_min = np.arange(-1.5, 1.5 + 1e-9, 0.5)
    #: Smallest drop of the fit part's whitened lab chi-square for which a shift is applied:
    #: the chi-square quantile of the verdict's significance level (0.001, one degree of
    #: freedom). A handful of lab results taken where the outlet moisture is flat do not pin
    #: a shift, and the grid's best then lands anywhere (a fold fitted on eight such results
    #: put 84.5 min on a 44 min delay); such a shift is noise and is not applied.
    min_chi2_drop = float(chi2_dist.isf(1e-3, 1))
    probe_size = 45.0
    probe_unit = "min"

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        _, values = self.lab_chi2(problem, np.array([self.probe_size]))
        return Prediction(problem.baseline.Y, values[0])

    @staticmethod
    def lab_chi2(problem: Problem, shifts_min: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For every shift [min], the whitened fit-part lab chi-square and the baseline
        model's ``moisture_out`` at the moved sample times (S, L), all shifts in one batched
        model step from the window-start states."""
        pts = [problem.lab_points(float(m) * 60e9) for m in shifts_min]
        L = problem.windows.lab_value.size
        cat = LabPoints(np.concatenate([p.window for p in pts]),
                        np.concatenate([p.offset for p in pts]),
                        np.concatenate([p.inputs for p in pts]))
        values = problem.baseline_labs(cat).reshape(len(pts), L)
        chi = np.array([problem.lab_chi2(v) for v in values])
        chi[~np.isfinite(chi)] = np.inf
        return chi, values

    def fit(self, problem: Problem) -> Fitted:
        base = problem.baseline
        fit = problem.split.lab_fit
        if not fit.any():
            return Fitted(self.cause, {"shift_min": 0.0}, self.n_params, base,
                          problem.chi2(base), "no lab result in the fit part: shift not fitted")
        chi, values = self.lab_chi2(problem, self.grid_min)
        i = int(np.argmin(chi))
        fine = np.clip(self.grid_min[i] + self.refine_min, self.grid_min[0], self.grid_min[-1])
        chi_f, values_f = self.lab_chi2(problem, fine)
        j = int(np.argmin(chi_f))
        chi0 = problem.lab_chi2(base.lab)
        delta, lab, best = float(fine[j]), values_f[j], float(chi_f[j])
        kept = ""
        if not chi0 - best >= self.min_chi2_drop:
            kept = (f"; the best shift, {delta:+.1f} min, lowers the whitened lab chi-square by "
                    f"only {chi0 - best:.1f} (needed: {self.min_chi2_drop:.1f}), so none is "
                    f"applied")
            delta, lab = 0.0, base.lab
        pred = Prediction(base.Y, lab)
        n = int(fit.sum())
        r0 = problem.residuals(base).lab[fit]
        r1 = problem.residuals(pred).lab[fit]
        when = "later" if delta > 0 else "earlier"
        return Fitted(self.cause, {"shift_min": delta}, self.n_params, pred, problem.chi2(pred),
                      f"lab samples were taken {abs(delta):.1f} min {when} than stamped "
                      f"(fit-part lab RMSE {math.sqrt(float(r0 @ r0) / n):.4f} -> "
                      f"{math.sqrt(float(r1 @ r1) / n):.4f} kg/kg{kept})")


class TransferDrift(Extension):
    """``fouling_drift``: ``mult_D`` and ``mult_h`` fall linearly, by ``d`` at the day's end,
    and the outputs move as the model's steady state says they do.

    The outputs drift by ``d t / T`` times the model's steady-state response to that loss at
    the day's mean inputs (``S``, per unit loss: a lost transfer leaves the gas hotter and the
    fibre wetter), over the windows and at the lab sample times. The drift is quasi-static:
    fouling builds over hours, and the model run with the multipliers falling (the first
    form) also changed its response to every input move, which the plant's fouling did not:
    on the independent plant it lowered the raw RMSE of every channel (``T_dryer_out`` 1.0 to
    0.34 K, the labs 0.0086 to 0.0055 kg/kg at a loss of 0.15) while the window-to-window
    errors it added cost more than the drift it removed against the plant's normal."""

    cause = "fouling_drift"
    bounds = (-1.0, 0.9)
    #: The loss at which the steady response is taken (a secant, not a derivative: the
    #: response bends as the transfer falls). [-]
    secant = 0.2

    def response(self, problem: Problem) -> np.ndarray:
        """``S`` (3,): the model's steady output change per unit transfer loss at the day's
        mean inputs (``T_dryer_out``, ``T_cyclone_out`` [K], ``moisture_out`` [kg/kg])."""
        u = problem.windows.U.mean(axis=0)
        lost = np.array(problem.theta, float)
        lost[_MULT_D] *= 1.0 - self.secant
        lost[_MULT_H] *= 1.0 - self.secant
        _, y0 = problem.model.steady_state(u, problem.theta)
        _, y1 = problem.model.steady_state(u, lost)
        return (np.asarray(y1, float) - np.asarray(y0, float)) / self.secant

    probe_size = 0.3
    probe_unit = "loss by the end of the day"

    def drifted(self, problem: Problem, S: np.ndarray, d: float,
                k_end: int | None = None) -> Prediction:
        """The baseline drifted by a loss ``d`` at the day's end (response ``S``) over the
        first ``k_end`` windows (default all)."""
        w = problem.windows
        base = problem.baseline
        t_win = w.day_fraction
        t_lab = w.lab_hours / float(w.hours[-1])
        k = w.n_windows if k_end is None else int(k_end)
        Y = base.Y[:k] + d * t_win[:k, None] * S
        lab = np.where(w.lab_window < k, base.lab + d * t_lab * S[2], np.nan)
        return Prediction(Y, lab)

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        return self.drifted(problem, self.response(problem), self.probe_size)

    def fit(self, problem: Problem) -> Fitted:
        w = problem.windows
        S = self.response(problem)

        def make(d: float, k_end: int | None) -> Prediction:
            return self.drifted(problem, S, d, k_end)

        d, chi = _fit_scalar(problem, make, self.bounds, step=0.05, tol=2e-3)
        trend = "lose" if d >= 0 else "gain"
        return Fitted(self.cause, {"loss_by_end": d}, self.n_params, make(d, None), chi,
                      f"tube heat and mass transfer (mult_h, mult_D) {trend} {abs(d):.0%} "
                      f"linearly over the {w.hours[-1]:.0f} h record: the outputs drift by "
                      f"{d * S[0]:+.2f} K, {d * S[1]:+.2f} K and {d * S[2]:+.4f} kg/kg by "
                      f"its end")


class AirSensorLag(Extension):
    """``input_lag``: the ``T_air_in`` sensor lags the air by a first-order ``tau``."""

    cause = "input_lag"
    bounds_min = (0.0, 45.0)
    probe_size = 8.0
    probe_unit = "min"

    @staticmethod
    def delagged(problem: Problem, tau_min: float, k_end: int | None = None) -> Prediction:
        """The model on ``T_air_in`` with a lag of ``tau_min`` undone."""
        w = problem.windows
        U, bins = delagged_air(w.segment, w.air_edges, tau_min * 60.0)
        return problem.predict(U, k_end=k_end, labs=problem.lab_points(U=U, bins=bins))

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        return self.delagged(problem, self.probe_size)

    def fit(self, problem: Problem) -> Fitted:
        def make(tau: float, k_end: int | None) -> Prediction:
            return self.delagged(problem, tau, k_end)

        tau, chi = _fit_scalar(problem, make, self.bounds_min, step=2.0, tol=0.05)
        return Fitted(self.cause, {"tau_min": tau}, self.n_params, make(tau, None), chi,
                      f"T_air_in sensor lags the air by a first-order time constant of "
                      f"{tau:.1f} min")


class AmbientHeatLoss(Extension):
    """``ambient_heat_loss``: outside heat loss grows by ``beta`` per K of ambient below
    283.15 K (model aux ``BETA_AMB``)."""

    cause = "ambient_heat_loss"
    bounds = (-0.1, 0.6)
    probe_size = 0.05
    probe_unit = "1/K"

    @staticmethod
    def with_beta(problem: Problem, beta: float, k_end: int | None = None) -> Prediction:
        """The model with the outside heat loss growing by ``beta`` per K of cold."""
        aux = np.zeros(N_AUX)
        aux[BETA_AMB] = beta
        return problem.predict(aux=aux, k_end=k_end)

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        return self.with_beta(problem, self.probe_size)

    def fit(self, problem: Problem) -> Fitted:
        def make(beta: float, k_end: int | None) -> Prediction:
            return self.with_beta(problem, beta, k_end)

        beta, chi = _fit_scalar(problem, make, self.bounds, step=0.02, tol=5e-4)
        return Fitted(self.cause, {"beta_amb_per_K": beta}, self.n_params, make(beta, None), chi,
                      f"outside heat loss scales by 1 {beta:+.3f}/K x (283.15 K - T_amb), "
                      f"i.e. {beta * 10:+.0%} per 10 K of cold")


class InletMoistureEstimate(Extension):
    """``inlet_moisture``: the inlet moisture as a disturbance tracked by the UKF."""

    cause = "inlet_moisture"
    #: Random-walk intensities tried on the fit part. [kg/kg / sqrt(h)]
    walks = (0.01, 0.04)
    probe_size = 0.15
    probe_unit = "kg/kg"

    def probe(self, problem: Problem, channel: str | None = None) -> Prediction:
        """A sustained change of the inlet moisture, seen through the model's steady response
        at the day's mean inputs (the filter tracks any course of it; a step held over the
        day is the course the others are told from)."""
        u = problem.windows.U.mean(axis=0)
        U = np.stack([u, u])
        U[1, _M_IN] += self.probe_size
        _, y = problem.model.steady_state(U, problem.theta)
        dy = np.asarray(y[1] - y[0], float)
        base = problem.baseline
        return Prediction(base.Y + dy, base.lab + dy[2])

    def estimator(self, problem: Problem, walk: float) -> UkfEstimator:
        """A UKF on the calibrated model with random-walk intensity ``walk``."""
        cfg = problem.config
        settings = dataclasses.replace(estimator_settings(cfg), moisture_in_walk=walk)
        return UkfEstimator(cfg, settings, model=problem.model)

    def run(self, problem: Problem, ukf: UkfEstimator) -> np.ndarray:
        """Tick ``ukf`` over the day's windows as the daemon hands them over, without the lab
        results; return the posterior inlet moisture after each (K,). [kg/kg]"""
        out = np.empty(problem.windows.n_windows)
        with _quiet(ukf_logger):
            nominal = float(problem.config.nominal.moisture_in)
            for k, w in enumerate(problem.windows.windows):
                v = ukf.tick(w).moisture_in
                out[k] = nominal if v is None else float(v)
        return out

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
            m_hat = self.run(problem, self.estimator(problem, walk))
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
