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

The temperature states and the lab state are independent (the lab's own bias state carries
the moisture part of a heat-input error), so two filters run: one over the windows with the
three temperature states, one over the lab results at their sample times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsensor.estimation.discrepancy import ErrorPriors
from softsensor.estimation.settings import estimator_settings
from softsensor.plantconfig import PlantConfig

#: The discrepancy states, in the order of :attr:`DiscrepancyModel.sigma`.
STATE_NAMES: tuple[str, ...] = ("T_common", "T_dryer_out", "T_cyclone_out", "moisture_out")
#: Which temperature states each temperature channel reads (2, 3).
_H = np.array([[1.0, 1.0, 0.0],
               [1.0, 0.0, 1.0]])


@dataclass(frozen=True)
class DiscrepancyModel:
    """The calibration-error alternative (module docstring).

    Attributes
    ----------
    sigma : numpy.ndarray, shape (4,)
        Stationary standard deviations of :data:`STATE_NAMES` [K, K, K, kg/kg].
    tau : numpy.ndarray, shape (4,)
        Their correlation times [s].
    noise : numpy.ndarray, shape (3,)
        White measurement noise of ``T_dryer_out``, ``T_cyclone_out`` [K] and the lab
        results [kg/kg].
    window_s : float
        Window length [s].
    source : str
        Where ``sigma`` and ``tau`` came from.
    """

    sigma: np.ndarray
    tau: np.ndarray
    noise: np.ndarray
    window_s: float
    source: str

    @classmethod
    def from_config(cls, config: PlantConfig, noise: np.ndarray) -> DiscrepancyModel:
        """The estimator's error states (:class:`ErrorPriors`, the heat input's offset read
        as the outlet temperatures' common one) with measurement noise ``noise`` (3,). Their
        sizes come from the calibration's ``[discrepancy]``; a config without one (nobody
        said how far off the model is) gets the estimator's defaults, 1 K common, 0.5 K per
        channel, 0.01 kg/kg on the labs."""
        p = ErrorPriors.from_config(config, estimator_settings(config), heat_gain=1.0)
        return cls(np.asarray(p.sigma, float), np.asarray(p.tau, float),
                   np.asarray(noise, float), float(config.solver.window), p.source)

    def whiten_temperatures(self, r: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (n, 2) of temperature residuals ``r`` (n, 2)
        of consecutive windows, NaN where a residual is missing. The filter starts from the
        stationary distribution; each window's two measurements update it in turn."""
        return self._temperature_filter(r)

    def _temperature_filter(self, r: np.ndarray) -> np.ndarray:
        a = np.exp(-self.window_s / self.tau[:3])
        s2 = self.sigma[:3] ** 2
        q = np.diag(s2 * (1.0 - a**2))
        R = self.noise[:2] ** 2
        x = np.zeros(3)
        P = np.diag(s2)
        white = np.full(r.shape, np.nan)
        for k in range(r.shape[0]):
            if k:
                x = a * x
                P = a[:, None] * P * a[None, :] + q
            for c in range(2):
                y = r[k, c]
                if not math.isfinite(y):
                    continue
                h = _H[c]
                Ph = P @ h
                S = float(h @ Ph) + R[c]
                nu = y - float(h @ x)
                white[k, c] = nu / math.sqrt(S)
                gain = Ph / S
                x = x + gain * nu
                P = P - np.outer(gain, Ph)
        return white

    def whiten_labs(self, r: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Whitened one-step prediction errors (m,) of lab residuals ``r`` at sample times
        ``t_s`` [s] (sorted), from the stationary distribution of the lab state."""
        s2 = float(self.sigma[3] ** 2)
        R = float(self.noise[2] ** 2)
        x, P = 0.0, s2
        out = np.full(r.shape, np.nan)
        for i in range(r.size):
            if i:
                a = math.exp(-max(float(t_s[i] - t_s[i - 1]), 0.0) / float(self.tau[3]))
                x, P = a * x, a * a * P + s2 * (1.0 - a * a)
            if not math.isfinite(r[i]):
                continue
            S = P + R
            nu = float(r[i]) - x
            out[i] = nu / math.sqrt(S)
            K = P / S
            x, P = x + K * nu, (1.0 - K) * P
        return out


__all__ = ["STATE_NAMES", "DiscrepancyModel"]
