"""Calibration error as an explicit alternative: the estimator's discrepancy states over the day.

A calibrated model on a day it was not fitted on is a few tenths of a kelvin and a few
thousandths of moisture off, the error wanders slowly with the load, and it is shared between
the two outlet temperatures (heat input, losses) more than it is one channel's. The estimator
carries that error as Ornstein-Uhlenbeck states whose sizes and correlation times come from the
calibration's validation day (:mod:`softsensor.estimation.state_space`, PARAMS.toml
``[discrepancy]``). The diagnosis carries the same states through the day's residuals
(measured minus model):

================= =============================================== =================== ========
state             moves                                           std                 corr.
                                                                                      time
================= =============================================== =================== ========
``T_common``      both outlet temperatures alike [K]              ``s_common``        ``tau_0``
``T_dryer_out``   ``T_dryer_out`` alone [K]                       ``s_dryer``         ``tau_1``
``T_cyclone_out`` ``T_cyclone_out`` alone [K]                     ``s_cyclone``       ``tau_2``
``moisture_out``  the lab results [kg/kg]                         ``s_moisture``      ``tau_3``
================= =============================================== =================== ========

plus white measurement noise of each channel's noise level. This is a linear Gaussian state
space model, so a Kalman filter turns any residual series into its one-step-ahead prediction
errors, each divided by its predicted standard deviation
(:meth:`CalibrationErrorModel.whiten_temperatures`,
:meth:`~CalibrationErrorModel.whiten_labs`).
The whitened residuals are what the calibration-error alternative cannot predict: their sum
of squares is minus twice its log-likelihood (up to a constant that depends only on which
samples exist), so

* an extension is fitted by least squares on its whitened fit-part residuals (generalised
  least squares under the discrepancy's covariance): it wins only by what it explains beyond
  "the calibration is a little off", and an offset on both temperatures or a slow wander no
  larger than the calibration left costs it nothing to leave alone;
* a sensor's offset is a calibration error far outside what the calibration left, on one
  channel only: the discrepancy pays for it through one channel's own state and its prior,
  the sensor-offset extension does not;
* the whitened residuals of a prediction over the day are prequential: each is predicted from
  the samples before it only.

The filter is the estimator's (:mod:`softsensor.estimation.state_space`: the same states,
their decay and process noise by the same rule, filterpy's ``predict`` and ``update``), run on
the residuals instead of through the model. With a history (PARAMS.toml's ``[model_error]``)
the states are the history's own structure (:func:`normal_states`): a level per day and a
wander about it.

The temperature states and the lab state are independent (the lab's own bias state carries
the moisture part of a heat-input error), so two filters run: one over the windows with the
three temperature states, one over the lab results at their sample times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from filterpy.kalman import predict as kf_predict
from filterpy.kalman import update as kf_update

from softsensor.estimation.model_error import CHANNELS, ModelError, model_error_of
from softsensor.estimation.settings import estimator_settings
from softsensor.estimation.state_space import ErrorPriors, error_decay, error_noise
from softsensor.plantconfig import PlantConfig

#: The discrepancy states: the estimator's first four error states
#: (:data:`~softsensor.estimation.state_space.ERROR_STATES`), the heat input's offset read as
#: the outlet temperatures' common one.
STATE_NAMES: tuple[str, ...] = ("T_common", "T_dryer_out", "T_cyclone_out", "moisture_out")
#: Which temperature states each temperature channel reads (2, 3).
_H = np.array([[1.0, 1.0, 0.0],
               [1.0, 0.0, 1.0]])


@dataclass(frozen=True)
class CalibrationErrorModel:
    """The calibration-error alternative (module docstring).

    Attributes
    ----------
    T_priors, lab_priors : ErrorPriors
        The states of the temperature filter and of the lab filter, in the estimator's terms
        (sizes, correlation times or random walks, starting correlation).
    T_map, lab_map : numpy.ndarray
        Which states each temperature channel (2, n) and the lab result (1, m) read.
    noise : numpy.ndarray, shape (3,)
        White measurement noise of ``T_dryer_out``, ``T_cyclone_out`` [K] and the lab
        results [kg/kg].
    window_s : float
        Window length [s].
    source : str
        Where the sizes came from.
    """

    T_priors: ErrorPriors
    lab_priors: ErrorPriors
    T_map: np.ndarray
    lab_map: np.ndarray
    noise: np.ndarray
    window_s: float
    source: str

    @property
    def sigma(self) -> np.ndarray:
        """Starting standard deviations of the temperature states, then the lab states."""
        return np.r_[self.T_priors.sigma, self.lab_priors.sigma]

    @classmethod
    def from_config(cls, config: PlantConfig, noise: np.ndarray) -> CalibrationErrorModel:
        """The plant's normal from the history's ``[model_error]`` (:func:`normal_states`),
        else the estimator's error states (:class:`ErrorPriors`: the heat input's offset read
        as the outlet temperatures' common one, the calibration's ``[discrepancy]`` or the
        estimator's defaults, 1 K common, 0.5 K per channel, 0.01 kg/kg on the labs), with
        measurement noise ``noise`` (3,)."""
        me = model_error_of(config)
        window = float(config.solver.window)
        if me is not None:
            return normal_states(me, noise, window)
        p = ErrorPriors.from_config(config, estimator_settings(config), heat_gain=1.0)
        T = ErrorPriors(p.sigma[:3], p.tau[:3], p.source, p.walk[:3], p.corr[:3, :3])
        lab = ErrorPriors(p.sigma[3:4], p.tau[3:4], p.source, p.walk[3:4], np.eye(1))
        return cls(T, lab, _H, np.ones((1, 1)), np.asarray(noise, float), window, p.source)

    def whiten_temperatures(self, r: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (n, 2) of temperature residuals ``r`` (n, 2)
        of consecutive windows, NaN where a residual is missing. The filter starts from the
        states' starting spread; each window's two measurements update it in turn."""
        pri = self.T_priors
        F = np.diag(error_decay(self.window_s, pri))
        Q = np.diag(error_noise(self.window_s, pri))
        R = self.noise[:2] ** 2
        x, P = np.zeros(len(pri.sigma)), pri.covariance()
        white = np.full(r.shape, np.nan)
        for k in range(r.shape[0]):
            if k:
                x, P = kf_predict(x, P, F, Q)
            for c in range(2):
                y = r[k, c]
                if not math.isfinite(y):
                    continue
                h = self.T_map[c][None, :]
                S = (h @ P @ h.T).item() + R[c]
                white[k, c] = (y - (h @ x).item()) / math.sqrt(S)
                x, P = kf_update(x, P, np.array([y]), np.array([[R[c]]]), h)
        return white

    def whiten_labs(self, r: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (m,) of lab residuals ``r`` at sample times
        ``t_s`` [s] (sorted), from the lab states' starting spread."""
        pri = self.lab_priors
        R = np.array([[float(self.noise[2] ** 2)]])
        x, P = np.zeros(len(pri.sigma)), pri.covariance()
        h = self.lab_map
        out = np.full(r.shape, np.nan)
        for i in range(r.size):
            if i:
                dt = max(float(t_s[i] - t_s[i - 1]), 0.0)
                x, P = kf_predict(x, P, np.diag(error_decay(dt, pri)),
                                  np.diag(error_noise(dt, pri)))
            if not math.isfinite(r[i]):
                continue
            S = (h @ P @ h.T).item() + float(R[0, 0])
            out[i] = (float(r[i]) - (h @ x).item()) / math.sqrt(S)
            x, P = kf_update(x, P, np.array([float(r[i])]), R, h)
        return out


#: Largest correlation of the day levels (the history's outlet temperatures move together at
#: 0.99 and more; a correlation of one would make the covariance singular).
MAX_CORRELATION = 0.98
#: The temperature filter of the plant's normal: each channel reads its day level and its
#: wander (states: level T_dryer_out, level T_cyclone_out, wander of each).
_H_NORMAL = np.array([[1.0, 0.0, 1.0, 0.0],
                      [0.0, 1.0, 0.0, 1.0]])


def normal_states(me: ModelError, noise: np.ndarray, window_s: float) -> CalibrationErrorModel:
    """The plant's normal as the history learned it (:mod:`softsensor.estimation.model_error`):
    per channel a day level (correlated across the temperatures as their day offsets were)
    plus a first-order wander about it, and the white noise the history left. A slow drift
    the wander cannot make (fouling) or a thermometer's offset the other does not share then
    stands out.

    The level stays put within the day, as the history's day offsets did; the estimator lets
    its offsets walk (``walk``, across the days a daemon runs), and with that walk here the
    filter took in fouling's drift: the fresh plants' fouling days then read as normal (3 of
    4 named ``none``), without it their drift shows (seed 4242)."""
    cov = me.day_covariance()
    d, c, m = (me.channel(n) for n in CHANNELS)
    sd_lvl = np.sqrt(np.clip(np.diag(cov)[:2], 1e-12, None))
    corr = np.eye(4)
    corr[:2, :2] = np.clip(cov[:2, :2] / np.outer(sd_lvl, sd_lvl), -MAX_CORRELATION,
                              MAX_CORRELATION)
    np.fill_diagonal(corr, 1.0)
    source = f"history [model_error] ({me.days} days): day levels and wander"
    T = ErrorPriors(np.r_[sd_lvl, d.wander_sd, c.wander_sd],
                    np.r_[np.inf, np.inf, d.wander_tau_h, c.wander_tau_h] * 3600.0, source,
                    np.zeros(4), corr)
    lab = ErrorPriors(np.r_[max(m.day_sd, 1e-12), m.wander_sd],
                      np.r_[np.inf, m.wander_tau_h * 3600.0], source, np.zeros(2),
                      np.eye(2))
    return CalibrationErrorModel(T, lab, _H_NORMAL, np.ones((1, 2)), np.asarray(noise, float),
                            window_s, source)


__all__ = ["STATE_NAMES", "CalibrationErrorModel", "normal_states"]
