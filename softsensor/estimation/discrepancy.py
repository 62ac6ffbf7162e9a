"""The filter's state: the inlet moisture and the model's own, slowly varying error.

A calibrated model misses a real dryer by a few kelvin and a few hundredths of moisture,
slowly varying and correlated between channels. A filter that does not expect that error
blames it on the only thing it can move, the inlet moisture, and publishes nonsense. So the
state carries the error explicitly (:data:`STATE_NAMES`):

* ``moisture_in`` [kg/kg], seen through :class:`InletTransform`: the filter's coordinate ``s``
  is mapped to the inlet moisture by a soft clip that is the identity inside the physical
  range and approaches its bounds smoothly outside, so every sigma point and every mean is a
  moisture the model can be run at. A walk of ``estimator.moisture_in_walk`` per sqrt(h) that
  returns to the nominal over ``estimator.moisture_in_tau_h`` (48 h) when nothing says
  otherwise.
* ``T_air_in_offset`` [K]: the model's energy balance is off (heat loss, heat input, hot-gas
  humidity, calibration), which shows as an offset common to both outlet temperatures. It is
  carried as an offset of the heat input the model sees, not of its outputs: a model whose
  outlet air runs 1 K warmer than the plant's dries its fibre too much for the plant's real
  outlet temperature, and shifting its heat input brings both the outlet temperatures and the
  outlet moisture to where the plant is (about 0.003 kg/kg per K of outlet temperature at the
  nominal point), while an offset added to the outputs would leave the moisture at the model's
  own, wrong, outlet temperature. Its prior is the calibration's common temperature error
  divided by the model's gain from ``T_air_in`` to the outlet temperatures.
* ``T_dryer_out_offset``, ``T_cyclone_out_offset`` [K]: each channel's own offset (one sensor
  or one part of the model).
* ``moisture_out_bias`` [kg/kg]: added to the model's outlet moisture (kinetics).

The four error states are first-order (Ornstein-Uhlenbeck) processes: ``b' = a b + w`` with
``a = exp(-dt / tau)`` and ``var(w) = sigma^2 (1 - a^2)``, so their prior stays ``N(0,
sigma^2)`` for ever. ``sigma`` and ``tau`` come from the calibration's residuals on data it was
not fitted on (PARAMS.toml's ``[discrepancy]``, :class:`~softsensor.calibration.pipeline.
Discrepancy`), or from ``[estimator]`` defaults when there is none. The inlet moisture and the
common offset both move both temperatures; the filter tells them apart by what the discrepancy
cannot do: the temperatures' response to the inlet moisture grows with the fibre load, and the
lab results see the inlet moisture through the outlet moisture.

Adaptive noise (:class:`AdaptiveNoise`): when a channel's normalised innovation squared stays
above one, the channel's error process gets more process noise until it averages one again
(Mehra 1972, covariance matching), so the band widens while the plant moves away from the model
and narrows again when it settles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.estimation.settings import EstimatorSettings
from softsensor.plantconfig import PlantConfig

#: Filter state layout; the inlet moisture first (it alone moves the model's sigma points).
STATE_NAMES: tuple[str, ...] = ("moisture_in", "T_air_in_offset", "T_dryer_out_offset",
                                "T_cyclone_out_offset", "moisture_out_bias")
X_IN, X_HEAT, X_TDRY, X_TCYC, X_BIAS = range(len(STATE_NAMES))
#: The states that enter the model (the others add to its outputs).
MODEL_STATES: tuple[int, ...] = (X_IN, X_HEAT)
#: Adaptive channels: the two outlet temperatures and the lab moisture.
ADAPT_CHANNELS: tuple[str, ...] = ("T_dryer_out", "T_cyclone_out", "moisture_out")


@dataclass(frozen=True)
class InletTransform:
    """Soft clip ``X = T(s)``: identity on ``[lo + m, hi - m]``, exponential approach to
    ``lo`` and ``hi`` outside (continuous with its first derivative). [kg/kg]"""

    lo: float
    hi: float
    margin: float

    def forward(self, s: np.ndarray | float) -> np.ndarray:
        s = np.asarray(s, float)
        a, b, m = self.lo + self.margin, self.hi - self.margin, self.margin
        up = b + m * (1.0 - np.exp(-(s - b) / m))
        dn = a - m * (1.0 - np.exp((s - a) / m))
        return np.where(s > b, up, np.where(s < a, dn, s))

    def inverse(self, x: np.ndarray | float) -> np.ndarray:
        x = np.clip(np.asarray(x, float), self.lo + 1e-9 * self.margin,
                    self.hi - 1e-9 * self.margin)
        a, b, m = self.lo + self.margin, self.hi - self.margin, self.margin
        up = b - m * np.log(1.0 - (x - b) / m)
        dn = a + m * np.log(1.0 - (a - x) / m)
        return np.where(x > b, up, np.where(x < a, dn, x))

    def derivative(self, s: np.ndarray | float) -> np.ndarray:
        s = np.asarray(s, float)
        a, b, m = self.lo + self.margin, self.hi - self.margin, self.margin
        return np.where(s > b, np.exp(-(s - b) / m), np.where(s < a, np.exp((s - a) / m), 1.0))

    def near_bound(self, s: float) -> bool:
        """True when ``T(s)`` lies in the outer half of a margin (pinned at a bound)."""
        x = float(self.forward(s))
        return x < self.lo + 0.5 * self.margin or x > self.hi - 0.5 * self.margin


@dataclass(frozen=True)
class ErrorPriors:
    """Stationary standard deviations [K of ``T_air_in``, K, K, kg/kg] and correlation times
    [s] of the four error states, and where they came from."""

    sigma: np.ndarray
    tau: np.ndarray
    source: str

    @classmethod
    def from_config(cls, config: PlantConfig, s: EstimatorSettings, heat_gain: float
                    ) -> ErrorPriors:
        """From the calibration's ``[discrepancy]`` (carried in ``config.extra`` by
        :func:`softsensor.plantconfig.load_parameters`), floored by the settings; else the
        settings' defaults. ``heat_gain`` [K/K] turns the common outlet-temperature error into
        the heat input's."""
        sigma = np.array([s.T_offset_std, s.T_channel_std, s.T_channel_std,
                          s.moisture_out_bias_std])
        tau = np.array([s.T_offset_tau_h, s.T_channel_tau_h, s.T_channel_tau_h,
                        s.moisture_out_bias_tau_h]) * 3600.0
        d = config.extra.get("discrepancy") or {}
        source = "estimator defaults"
        if d:
            found = {k: float(v) for k, v in d.items() if isinstance(v, (int, float))
                     and math.isfinite(float(v))}
            fitted = [found.get("common_std"), found.get("dryer_std"),
                      found.get("cyclone_std"), found.get("moisture_std")]
            for i, v in enumerate(fitted):
                if v is not None:
                    sigma[i] = max(v, s.discrepancy_floor[i])
            if "tau_s" in found and found["tau_s"] > 0:
                # the default is a floor: the validation day's lag-one autocorrelation sees
                # how fast the error wanders, not how long its offset persists
                tau[0] = np.clip(found["tau_s"], tau[0], 48 * 3600.0)
            source = "calibration [discrepancy]"
        sigma[0] /= max(heat_gain, 1e-3)
        return cls(sigma=sigma, tau=tau, source=source)


def transition(window_s: float, priors: ErrorPriors, inlet_tau_s: float) -> np.ndarray:
    """The state transition matrix ``F`` (diagonal) over one window: the inlet moisture's
    deviation from the nominal and the error states decay by ``exp(-dt / tau)``."""
    a = np.exp(-window_s / priors.tau)
    return np.diag(np.r_[math.exp(-window_s / inlet_tau_s), a])


def process_noise(window_s: float, priors: ErrorPriors, walk_s: float, inlet_tau_s: float
                  ) -> np.ndarray:
    """Diagonal (5,) of the process noise ``Q`` over one window, before the adaptive inflation
    (constant for given settings; the filter multiplies the error states' entries by
    :meth:`AdaptiveNoise.inflation` each tick): the inlet moisture's walk ``walk_s`` per window
    (in the filter's coordinate; ``walk_s^2 (1 - a^2) / (2 dt / tau)`` with its mean
    reversion) and ``sigma^2 (1 - a^2)`` of each error state."""
    a = np.exp(-window_s / priors.tau)
    q_err = priors.sigma**2 * (1.0 - a**2)
    r = window_s / inlet_tau_s
    q_in = walk_s**2 * (1.0 - math.exp(-2.0 * r)) / (2.0 * r)
    return np.r_[q_in, q_err]


@dataclass
class AdaptiveNoise:
    """Per channel (:data:`ADAPT_CHANNELS`) a factor on the process noise of the error states
    it drives, adjusted every tick so that the channel's normalised innovation squared
    ``nu^2 / S`` averages one: ``f <- f (1 + (min(nu^2 / S, 9) - 1) / n)``, kept in ``[1,
    limit]``. A consistent filter leaves it near one; a plant that moves faster than the
    calibration said raises it until the band is honest again (an integral action on the
    innovations, memory about ``n`` ticks)."""

    factor: np.ndarray

    @classmethod
    def fresh(cls) -> AdaptiveNoise:
        return cls(np.ones(len(ADAPT_CHANNELS)))

    def update(self, channel: int, nu2_over_s: float, n: int, limit: float) -> None:
        r = min(max(nu2_over_s, 0.0), 9.0)
        f = self.factor[channel] * (1.0 + (r - 1.0) / max(n, 1))
        self.factor[channel] = min(max(f, 1.0), limit)

    def inflation(self) -> np.ndarray:
        """Inflation (4,) of the error states' process noise: the temperature channels drive
        their own offsets and, through the smaller of the two, the heat input's; the lab
        channel the outlet-moisture bias."""
        f = self.factor
        return np.array([min(f[0], f[1]), f[0], f[1], f[2]])

    def to_json(self) -> dict[str, Any]:
        return {"factor": self.factor.tolist()}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> AdaptiveNoise:
        return cls(np.array(d["factor"], float))


__all__ = ["ADAPT_CHANNELS", "MODEL_STATES", "STATE_NAMES", "X_BIAS", "X_HEAT", "X_IN", "X_TCYC",
           "X_TDRY",
           "AdaptiveNoise", "ErrorPriors", "InletTransform", "process_noise", "transition"]
