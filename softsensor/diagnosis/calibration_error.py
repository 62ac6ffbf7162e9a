"""Calibration error as an explicit alternative: the estimator's discrepancy states over the day.

A calibrated model on a day it was not fitted on is a few tenths of a kelvin and a few
thousandths of moisture off, the error wanders slowly with the load, and it is shared between
the two outlet temperatures (heat input, losses) more than it is one channel's. The estimator
carries that error as Ornstein-Uhlenbeck states whose sizes and correlation times come from the
calibration's validation day (:mod:`softsensor.estimation.discrepancy`, PARAMS.toml
``[discrepancy]``). The diagnosis carries the same states through the day's residuals
(measured minus model):

================ =============================================== =================== ========
state            moves                                           std                 corr.
                                                                                     time
================ =============================================== =================== ========
``T_common``     both outlet temperatures alike [K]              ``s_common``        ``tau_0``
``T_dryer_out``  ``T_dryer_out`` alone [K]                       ``s_dryer``         ``tau_1``
``T_cyclone_out`` ``T_cyclone_out`` alone [K]                    ``s_cyclone``       ``tau_2``
``moisture_out`` the lab results [kg/kg]                         ``s_moisture``      ``tau_3``
================ =============================================== =================== ========

plus white measurement noise of each channel's noise level. This is a linear Gaussian state
space model, so a Kalman filter turns any residual series into its one-step-ahead prediction
errors, each divided by its predicted standard deviation (:meth:`DiscrepancyModel.whiten`).
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

The filter is the estimator's (:mod:`softsensor.estimation.discrepancy`: the same states,
their decay and process noise by the same rule, filterpy's ``predict`` and ``update``), run on
the residuals instead of through the model. With a history (PARAMS.toml's ``[model_error]``)
the channel states are random walks from the history's day-to-day spread, as the
estimator's are.

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

from softsensor.estimation.discrepancy import ErrorPriors, error_decay, error_noise
from softsensor.estimation.settings import estimator_settings
from softsensor.plantconfig import PlantConfig

#: The discrepancy states: the estimator's first four error states
#: (:data:`~softsensor.estimation.discrepancy.ERROR_STATES`), the heat input's offset read as
#: the outlet temperatures' common one.
STATE_NAMES: tuple[str, ...] = ("T_common", "T_dryer_out", "T_cyclone_out", "moisture_out")
#: Which temperature states each temperature channel reads (2, 3).
_H = np.array([[1.0, 1.0, 0.0],
               [1.0, 0.0, 1.0]])


@dataclass(frozen=True)
class DiscrepancyModel:
    """The calibration-error alternative (module docstring).

    Attributes
    ----------
    priors : ErrorPriors
        The estimator's error states (sizes, correlation times or random walks), the heat
        input's read as the outlet temperatures' common offset (a heat gain of one).
    noise : numpy.ndarray, shape (3,)
        White measurement noise of ``T_dryer_out``, ``T_cyclone_out`` [K] and the lab
        results [kg/kg].
    window_s : float
        Window length [s].
    """

    priors: ErrorPriors
    noise: np.ndarray
    window_s: float

    @property
    def sigma(self) -> np.ndarray:
        """Starting standard deviations of :data:`STATE_NAMES` [K, K, K, kg/kg]."""
        return np.asarray(self.priors.sigma[:4], float)

    @property
    def source(self) -> str:
        return self.priors.source

    @classmethod
    def from_config(cls, config: PlantConfig, noise: np.ndarray) -> DiscrepancyModel:
        """The estimator's error states (:class:`ErrorPriors`) with measurement noise
        ``noise`` (3,). Their sizes come from the history's ``[model_error]`` and the
        calibration's ``[discrepancy]``; a config without either (nobody said how far off the
        model is) gets the estimator's defaults, 1 K common, 0.5 K per channel, 0.01 kg/kg
        on the labs."""
        p = ErrorPriors.from_config(config, estimator_settings(config), heat_gain=1.0)
        return cls(p, np.asarray(noise, float), float(config.solver.window))

    def _decay_noise(self, dt_s: float, states: slice) -> tuple[np.ndarray, np.ndarray]:
        """``F`` and ``Q`` of the ``states`` over ``dt_s`` [s] (the estimator's rule)."""
        return (np.diag(error_decay(dt_s, self.priors)[states]),
                np.diag(error_noise(dt_s, self.priors)[states]))

    def whiten_temperatures(self, r: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (n, 2) of temperature residuals ``r`` (n, 2)
        of consecutive windows, NaN where a residual is missing. The filter starts from the
        states' starting spread; each window's two measurements update it in turn."""
        F, Q = self._decay_noise(self.window_s, slice(0, 3))
        R = self.noise[:2] ** 2
        x, P = np.zeros(3), np.diag(self.sigma[:3] ** 2)
        white = np.full(r.shape, np.nan)
        for k in range(r.shape[0]):
            if k:
                x, P = kf_predict(x, P, F, Q)
            for c in range(2):
                y = r[k, c]
                if not math.isfinite(y):
                    continue
                h = _H[c][None, :]
                S = (h @ P @ h.T).item() + R[c]
                white[k, c] = (y - (h @ x).item()) / math.sqrt(S)
                x, P = kf_update(x, P, np.array([y]), np.array([[R[c]]]), h)
        return white

    def whiten_labs(self, r: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (m,) of lab residuals ``r`` at sample times
        ``t_s`` [s] (sorted), from the lab state's starting spread."""
        R = np.array([[float(self.noise[2] ** 2)]])
        x, P = np.zeros(1), np.array([[float(self.sigma[3] ** 2)]])
        h = np.ones((1, 1))
        out = np.full(r.shape, np.nan)
        for i in range(r.size):
            if i:
                F, Q = self._decay_noise(max(float(t_s[i] - t_s[i - 1]), 0.0), slice(3, 4))
                x, P = kf_predict(x, P, F, Q)
            if not math.isfinite(r[i]):
                continue
            out[i] = (float(r[i]) - float(x[0])) / math.sqrt(float(P[0, 0]) + float(R[0, 0]))
            x, P = kf_update(x, P, np.array([float(r[i])]), R, h)
        return out


__all__ = ["STATE_NAMES", "DiscrepancyModel"]
