"""The filter's state: the inlet moisture and the model's own, slowly varying error.

A calibrated model misses a real dryer by a few kelvin and a few hundredths of moisture,
slowly varying and correlated between channels. A filter that does not expect that error
blames it on the only thing it can move, the inlet moisture, and publishes nonsense. So the
state carries the error explicitly (:data:`STATE_NAMES`):

* ``moisture_in`` [kg/kg], seen through :class:`InletTransform`: the filter's coordinate ``s``
  is mapped to the inlet moisture by a soft clip that is the identity inside the physical
  range and approaches its bounds smoothly outside, so every sigma point and every mean is a
  moisture the model can be run at. A walk of ``estimator.moisture_in_walk`` per sqrt(h) that
  returns to its reference (the history's typical level, else the nominal) over
  ``estimator.moisture_in_tau_h`` (48 h) when nothing says otherwise.
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
* ``inlet_gain`` [-]: the relative error of the model's outlet-moisture response to the
  inlet moisture. The published (and lab-compared) outlet moisture is ``y(X_ref) + (1 +
  inlet_gain) (y(X) - y(X_ref))`` plus the bias, with ``X_ref`` the inlet moisture's
  reference: a dryer whose fibre leaves nearer its equilibrium than the model's responds less
  to a wetter feed, and no clean day of history can say by how much (the inlet moisture
  barely moves on one). The labs teach it online whenever the inlet moisture moves, instead
  of the bias jumping back at every result.

The error states are first-order (Ornstein-Uhlenbeck) processes ``b' = a b + w`` with ``a =
exp(-dt / tau)`` and ``var(w) = sigma^2 (1 - a^2)`` (prior ``N(0, sigma^2)`` for ever), or,
with ``tau = inf``, random walks (``var(w) = walk^2 dt``, ``sigma`` their spread at the
start). Without a history the four error states of the outputs come from the calibration's
residuals on data it was not fitted on (PARAMS.toml's ``[discrepancy]``) or from
``[estimator]`` defaults; with one (``[model_error]``, :mod:`.model_error`) the two channel
offsets and the bias are random walks sized by the history's day-to-day spread and within-day
wander: one integrating disturbance per measured output, so the filter is offset-free
(Pannocchia and Rawlings, AIChE J. 49, 2003). ``inlet_gain`` is a random walk from
``estimator.inlet_gain_std`` and ``inlet_gain_walk``, by default only with a history (a
model nobody has compared with its plant keeps it at zero; what it gave is in
``docs/explanation/estimator.md``). With it the labs no longer pin the inlet moisture (a
temperature offset may pass for an inlet moisture whose outlet effect the gain cancels): the
temperatures and the history's typical level carry it.

Adaptive noise (:class:`AdaptiveNoise`): when a channel's normalised innovation squared stays
above one, the channel's error process gets more process noise until it averages one again
(Mehra 1972, covariance matching), so the band widens while the plant moves away from the model
and narrows again when it settles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.estimation.model_error import model_error_of
from softsensor.estimation.settings import EstimatorSettings
from softsensor.plantconfig import DiscrepancyPrior, PlantConfig, discrepancy_of

#: Filter state layout; the inlet moisture first (it alone moves the model's sigma points with
#: the heat input's offset).
STATE_NAMES: tuple[str, ...] = ("moisture_in", "T_air_in_offset", "T_dryer_out_offset",
                                "T_cyclone_out_offset", "moisture_out_bias", "inlet_gain")
X_IN, X_HEAT, X_TDRY, X_TCYC, X_BIAS, X_GAIN = range(len(STATE_NAMES))
#: The error states (every state but the inlet moisture), in state order.
ERROR_STATES: tuple[str, ...] = STATE_NAMES[1:]
#: Units of the states, for messages.
STATE_UNITS: dict[str, str] = {"moisture_in": "kg/kg", "T_air_in_offset": "K",
                               "T_dryer_out_offset": "K", "T_cyclone_out_offset": "K",
                               "moisture_out_bias": "kg/kg", "inlet_gain": "-"}
#: The states that enter the model (the others act on its outputs).
MODEL_STATES: tuple[int, ...] = (X_IN, X_HEAT)
#: The inlet gain's prior standard deviation with a history (``estimator.inlet_gain_std``
#: unset), and the one that holds it at zero without one [-].
DEFAULT_INLET_GAIN_STD = 1.0
HELD_INLET_GAIN_STD = 1e-9
#: Smallest response of the plant's outlet moisture to its inlet moisture, as a share of the
#: model's (``1 + inlet_gain``): a wetter feed never leaves a drier fibre (the drying rate
#: falls as the fibre dries, so the outlet moisture rises with the inlet's, Wood Handbook
#: ch. 13; a response near zero is a dryer that takes any feed to equilibrium) [-].
GAIN_RESPONSE_FLOOR = 0.05
#: Sharpness of the soft floor (per unit of response): within 1e-3 of the identity 0.35 above
#: the floor.
_GAIN_SHARPNESS = 20.0


def gain_response(g: np.ndarray | float) -> np.ndarray:
    """The response ``1 + inlet_gain`` bounded below by :data:`GAIN_RESPONSE_FLOOR`,
    smoothly (a softplus): the identity while the response is well above the floor, so the
    filter's mean and the sigma points far from the floor are unchanged, and never an
    inverted response however far a sigma point reaches (issue 47: 1 + g = -1.65 was seen).
    [-]"""
    z = (1.0 + np.asarray(g, float) - GAIN_RESPONSE_FLOOR) * _GAIN_SHARPNESS
    return GAIN_RESPONSE_FLOOR + np.logaddexp(0.0, z) / _GAIN_SHARPNESS


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
        # each branch evaluated only on its own side (no overflow far outside the range)
        up = b + m * (1.0 - np.exp(-(np.maximum(s, b) - b) / m))
        dn = a - m * (1.0 - np.exp((np.minimum(s, a) - a) / m))
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
        return np.where(s > b, np.exp(-(np.maximum(s, b) - b) / m),
                        np.where(s < a, np.exp((np.minimum(s, a) - a) / m), 1.0))

    def near_bound(self, s: float) -> bool:
        """True when ``T(s)`` lies in the outer half of a margin (pinned at a bound)."""
        x = float(self.forward(s))
        return x < self.lo + 0.5 * self.margin or x > self.hi - 0.5 * self.margin


@dataclass(frozen=True)
class ErrorPriors:
    """Per error state (:data:`ERROR_STATES` order): standard deviation ``sigma`` [unit],
    correlation time ``tau`` [s] (``inf``: a random walk), walk intensity ``walk``
    [unit/sqrt(s)] of a random walk, and where they came from (module docstring)."""

    sigma: np.ndarray
    tau: np.ndarray
    source: str
    walk: np.ndarray = field(default_factory=lambda: np.zeros(len(ERROR_STATES)))
    corr: np.ndarray = field(default_factory=lambda: np.eye(len(ERROR_STATES)))

    def sd(self, name: str) -> float:
        """``sigma`` of the error state ``name``."""
        return float(self.sigma[ERROR_STATES.index(name)])

    def covariance(self) -> np.ndarray:
        """The error states' covariance at the start: ``sigma`` with the correlation the
        history's day offsets showed (:attr:`corr`, the identity without a history)."""
        return self.corr * np.outer(self.sigma, self.sigma)

    @classmethod
    def from_config(cls, config: PlantConfig, s: EstimatorSettings, heat_gain: float
                    ) -> ErrorPriors:
        """From the history's ``[model_error]`` (channel offsets and bias) and the
        calibration's ``[discrepancy]`` (the heat input's offset), carried in
        ``config.extra`` by :func:`softsensor.plantconfig.load_parameters`, floored by the
        settings; else the settings' defaults. ``heat_gain`` [K/K] turns the common
        outlet-temperature error into the heat input's."""
        me = model_error_of(config)
        gain_sd = s.inlet_gain_std if s.inlet_gain_std is not None else (
            DEFAULT_INLET_GAIN_STD if me is not None else HELD_INLET_GAIN_STD)
        sigma = np.array([s.T_offset_std, s.T_channel_std, s.T_channel_std,
                          s.moisture_out_bias_std, gain_sd])
        tau = np.array([s.T_offset_tau_h, s.T_channel_tau_h, s.T_channel_tau_h,
                        s.moisture_out_bias_tau_h, math.inf]) * 3600.0
        walk = np.zeros(len(ERROR_STATES))
        if gain_sd > HELD_INLET_GAIN_STD:
            walk[-1] = s.inlet_gain_walk / 60.0  # per sqrt(h) -> per sqrt(s)
        source = _from_discrepancy(config, s, sigma, tau)
        sigma[0] /= max(heat_gain, 1e-3)
        if me is not None:
            # how each channel's offset spreads from day to day and wanders within a day
            for i, name in enumerate(("T_dryer_out", "T_cyclone_out", "moisture_out"),
                                     start=1):
                ch = me.channel(name)
                sigma[i] = max(ch.day_sd, s.discrepancy_floor[i])
                tau[i] = math.inf
                walk[i] = ch.walk / 60.0
            source = f"history [model_error] ({me.days} days)"
            # the states start uncorrelated although the history's day offsets move
            # together (0.99 between the outlet temperatures): started with that correlation
            # the filter did worse on the tuning plants (pooled 0.0086 against 0.0083 kg/kg,
            # below the regression on 13 against 15 of 24 days); the diagnosis uses it
        return cls(sigma=sigma, tau=tau, source=source, walk=walk)


def _from_discrepancy(config: PlantConfig, s: EstimatorSettings, sigma: np.ndarray,
                      tau: np.ndarray) -> str:
    """Fill ``sigma``/``tau`` of the four output error states from the calibration's
    ``[discrepancy]`` (in place); returns where the numbers came from."""
    d = discrepancy_of(config)
    if d is None or d == DiscrepancyPrior():
        return "estimator defaults"
    fitted = [d.common_std, d.dryer_std, d.cyclone_std, d.moisture_std]
    for i, v in enumerate(fitted):
        if v is not None:
            sigma[i] = max(v, s.discrepancy_floor[i])
    if d.tau_s is not None:
        # the default is a floor: the validation day's lag-one autocorrelation sees how fast
        # the error wanders, not how long its offset persists
        tau[0] = np.clip(d.tau_s, tau[0], 48 * 3600.0)
    return "calibration [discrepancy]"


def error_decay(dt_s: float, priors: ErrorPriors) -> np.ndarray:
    """How much of each error state is left after ``dt_s`` [s]: ``exp(-dt / tau)``, one for a
    random walk (:data:`ERROR_STATES` order). The one rule the estimator and the diagnosis's
    calibration-error filter share."""
    return np.exp(-float(dt_s) / priors.tau)


def error_noise(dt_s: float, priors: ErrorPriors) -> np.ndarray:
    """Variance each error state gains over ``dt_s`` [s] (:data:`ERROR_STATES` order):
    ``sigma^2 (1 - a^2)`` of a first-order process (its variance stays ``sigma^2``),
    ``walk^2 dt`` of a random walk."""
    a = error_decay(dt_s, priors)
    return np.where(np.isinf(priors.tau), priors.walk**2 * float(dt_s),
                    priors.sigma**2 * (1.0 - a**2))


def transition(window_s: float, priors: ErrorPriors, inlet_tau_s: float) -> np.ndarray:
    """The state transition matrix ``F`` (diagonal) over one window: the inlet moisture's
    deviation from its reference and the first-order error states decay by ``exp(-dt /
    tau)``; random walks stay."""
    return np.diag(np.r_[math.exp(-window_s / inlet_tau_s), error_decay(window_s, priors)])


def process_noise(window_s: float, priors: ErrorPriors, walk_s: float, inlet_tau_s: float
                  ) -> np.ndarray:
    """Diagonal of the process noise ``Q`` over one window, before the adaptive inflation
    (constant for given settings; the filter multiplies the error states' entries by
    :meth:`AdaptiveNoise.inflation` each tick): the inlet moisture's walk ``walk_s`` per window
    (in the filter's coordinate; ``walk_s^2 (1 - a^2) / (2 dt / tau)`` with its mean
    reversion), ``sigma^2 (1 - a^2)`` of each first-order error state and ``walk^2 dt`` of
    each random walk."""
    r = window_s / inlet_tau_s
    q_in = walk_s**2 * (1.0 - math.exp(-2.0 * r)) / (2.0 * r)
    return np.r_[q_in, error_noise(window_s, priors)]


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
        """Inflation of the error states' process noise (:data:`ERROR_STATES` order): the
        temperature channels drive their own offsets and, through the smaller of the two, the
        heat input's; the lab channel the outlet-moisture bias and the inlet gain."""
        f = self.factor
        return np.array([min(f[0], f[1]), f[0], f[1], f[2], f[2]])

    def to_json(self) -> dict[str, Any]:
        return {"factor": self.factor.tolist()}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> AdaptiveNoise:
        return cls(np.array(d["factor"], float))


__all__ = ["ADAPT_CHANNELS", "ERROR_STATES", "GAIN_RESPONSE_FLOOR", "MODEL_STATES",
           "STATE_NAMES", "STATE_UNITS",
           "X_BIAS", "X_GAIN", "X_HEAT", "X_IN", "X_TCYC", "X_TDRY",
           "AdaptiveNoise", "ErrorPriors", "InletTransform", "error_decay", "error_noise",
           "gain_response", "process_noise", "transition"]
