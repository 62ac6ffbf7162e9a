"""How the calibrated model misses its dryer on normal days, learned from the plant's history.

A calibrated model is never the plant: its response to load and set-point moves has the
wrong size, each day sits at its own offset, and the offsets wander. One day cannot tell these
apart; many clean days can. :mod:`softsensor.calibration.model_error_fit` learns them from the
history's residuals (measured minus the calibrated model run open loop on the measured inputs,
at the history's typical inlet moisture) and this module holds the result, PARAMS.toml's
``[model_error]``, and evaluates it for the estimator and the diagnosis.

Per output channel ``c`` (``T_dryer_out`` [K], ``T_cyclone_out`` [K], lab ``moisture_out``
[kg/kg]) the residual of window (or lab sample) ``t`` of day ``i`` is modelled as

    r_c(i, t) = g_c(phi(t)) + d_c(i) + w_c(i, t) + e_c(i, t),
    g_c(phi) = intercept_c + coef_c . (phi - mean) / scale,

a discrepancy linear in the standardised operating point ``phi`` (window means of the measured
inputs and the set point, :data:`~softsensor.estimation.model_error.FEATURES`) in the manner of
Kennedy and O'Hagan's additive model discrepancy (J. R. Stat. Soc. B 63, 2001, eq. 5), a day offset
``d ~ N(0, day_sd^2)`` (correlated across the channels, ``day_cov``), a first-order wander ``w``
about it (``wander_sd``, ``wander_tau_h``) and white noise ``e`` of standard deviation ``noise``.
The estimator adds ``g_c`` to its measurement model (its
uncertainty ``phi' C phi`` to the variance) and carries ``d + w`` as the error state of the
channel (a random walk: an integrating disturbance per measured output, so the filter is
offset-free, Pannocchia and Rawlings, AIChE J. 49, 2003); the diagnosis judges a day against
these numbers (the plant's normal).

``coef`` is zero for a channel where the learned discrepancy did not predict held-out days
better than none (``rmse_held_out >= rmse_without``): then only the offsets remain.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from softsensor.configfile import build_section, num
from softsensor.errors import ConfigError
from softsensor.plantconfig import PlantConfig, built_table
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES, SCAN_SIGNALS

#: The operating point the discrepancy is a function of: the measured model inputs and the
#: set point of the outlet loop (window means; SI).
FEATURES: tuple[str, ...] = (*INPUT_NAMES[:-1], "T_sp")
#: The output channels, in :data:`~softsensor.signals.OUTPUT_NAMES` order.
CHANNELS: tuple[str, ...] = OUTPUT_NAMES


@dataclass(frozen=True)
class ChannelError:
    """How the model misses one output channel (module docstring), in the channel's unit.

    Attributes
    ----------
    coef : tuple of float
        Discrepancy per standard deviation of each feature [unit].
    coef_cov : tuple of float
        Covariance of ``coef``, row-major ``F x F`` [unit^2].
    intercept : float
        Mean of the day offsets [unit].
    day_sd : float
        Standard deviation of the day offsets about it [unit].
    walk : float
        Random-walk intensity of the day level, which moves by ``day_sd`` in a day
        [unit/sqrt(h)].
    noise : float
        White residual of one sample (a window mean, or a lab result) [unit].
    wander_sd, wander_tau_h : float
        Standard deviation [unit] and correlation time [h] of the first-order wander about
        the day level.
    rmse_without, rmse_held_out : float
        Within-day RMSE (day mean removed) of the residuals without the discrepancy, and with
        it fitted on the other days (leave one day out) [unit].
    samples : int
        Residuals behind these numbers.
    """

    coef: tuple[float, ...]
    coef_cov: tuple[float, ...]
    intercept: float = num()
    day_sd: float = num(ge=0)
    walk: float = num(ge=0)
    noise: float = num(ge=0)
    rmse_without: float = num(ge=0)
    rmse_held_out: float = num(ge=0)
    samples: int = num(ge=0)
    wander_sd: float = num(0.0, ge=0)
    wander_tau_h: float = num(1.0, gt=0)

    def check(self) -> str | None:
        n = len(self.coef)
        if len(self.coef_cov) != n * n:
            return f"coef_cov must hold {n * n} numbers (coef has {n}), got {len(self.coef_cov)}"
        return None

    @property
    def cov(self) -> np.ndarray:
        n = len(self.coef)
        return np.asarray(self.coef_cov, float).reshape(n, n)

    @property
    def learned(self) -> bool:
        """True when the discrepancy is used (not all coefficients zero)."""
        return any(c != 0.0 for c in self.coef)


@dataclass(frozen=True)
class ModelError:
    """PARAMS.toml's ``[model_error]``: the learned discrepancy of every channel.

    Attributes
    ----------
    features : tuple of str
        Names of the operating-point features, scan signals
        (:data:`~softsensor.estimation.model_error.FEATURES`).
    mean, scale : tuple of float
        Their means and standard deviations over the history's windows (SI).
    days : int
        History days it was learned from.
    hours : float
        Hours of history.
    moisture_in : float
        The history's typical inlet moisture (mean of the calibration's day levels), at which
        the residuals were taken and where the estimator starts [kg/kg].
    moisture_in_day_sd : float
        Spread of the days' inlet-moisture levels about it [kg/kg].
    latest_moisture_in : float
        The latest history day's inlet-moisture level [kg/kg]: the dryer's current state,
        where the estimator starts (it reverts towards ``moisture_in`` over
        ``estimator.moisture_in_tau_h``); 0: none given (it starts at ``moisture_in``).
    day_cov : tuple of float
        Covariance of the channels' day offsets, row-major ``3 x 3`` in
        :data:`~softsensor.estimation.model_error.CHANNELS` order [unit x unit] (empty:
        uncorrelated, from each channel's ``day_sd``). On the independent plant the two outlet
        temperatures' day offsets move together (correlation 0.99: one energy balance) and the
        lab's follows them, so the diagnosis judges a day against correlated day offsets and a
        thermometer's own offset stands out (the estimator starts uncorrelated, which measured
        better:
        :meth:`~softsensor.estimation.state_space.ErrorPriors.from_config`).
    T_dryer_out, T_cyclone_out, moisture_out : ChannelError
        Per channel.
    """

    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    T_dryer_out: ChannelError
    T_cyclone_out: ChannelError
    moisture_out: ChannelError
    days: int = num(1, ge=1)
    hours: float = num(0.0, ge=0)
    moisture_in: float = num(1.0, gt=0, lt=5)
    moisture_in_day_sd: float = num(0.0, ge=0, lt=2)
    latest_moisture_in: float = num(0.0, ge=0, lt=5)
    day_cov: tuple[float, ...] = ()

    def check(self) -> str | None:
        unknown = [f for f in self.features if f not in SCAN_SIGNALS]
        if unknown:
            return f"features: {unknown[0]!r} is not a scan signal"
        n = len(self.features)
        if len(self.mean) != n or len(self.scale) != n:
            return f"mean and scale must hold one number per feature ({n})"
        if any(not s > 0 for s in self.scale):
            return "scale must be > 0 for every feature"
        for name in CHANNELS:
            if len(self.channel(name).coef) != n:
                return f"{name}.coef must hold one number per feature ({n})"
        c = len(CHANNELS)
        if self.day_cov and len(self.day_cov) != c * c:
            return f"day_cov must hold {c * c} numbers, got {len(self.day_cov)}"
        return None

    @property
    def start_moisture_in(self) -> float:
        """Where the estimator starts its inlet moisture [kg/kg]: the latest day's level,
        else the history's."""
        return self.latest_moisture_in or self.moisture_in

    def day_covariance(self) -> np.ndarray:
        """Covariance (3, 3) of the channels' day offsets, in
        :data:`~softsensor.estimation.model_error.CHANNELS` order (from
        the day spreads alone, uncorrelated, when the table has none)."""
        c = len(CHANNELS)
        if self.day_cov:
            return np.asarray(self.day_cov, float).reshape(c, c)
        return np.diag([self.channel(n).day_sd ** 2 for n in CHANNELS])

    def channel(self, name: str) -> ChannelError:
        """The :class:`ChannelError` of output channel ``name``."""
        if name not in CHANNELS:
            raise KeyError(name)
        return getattr(self, name)

    def phi(self, means: Mapping[str, float | None]) -> np.ndarray:
        """The standardised operating point of window means ``means`` (a missing or
        non-finite feature sits at its history mean, so it contributes nothing)."""
        out = np.zeros(len(self.features))
        for j, (name, m, s) in enumerate(zip(self.features, self.mean, self.scale,
                                              strict=True)):
            v = means.get(name)
            if v is not None and math.isfinite(v):
                out[j] = (float(v) - m) / s
        return out

    def phi_matrix(self, columns: Mapping[str, np.ndarray]) -> np.ndarray:
        """Standardised features (N, F) from arrays of window means by name (NaN: mean)."""
        cols = []
        for name, m, s in zip(self.features, self.mean, self.scale, strict=True):
            z = (np.asarray(columns[name], float) - m) / s
            cols.append(np.where(np.isfinite(z), z, 0.0))
        return np.stack(cols, axis=-1)

    def offset(self, name: str, phi: np.ndarray) -> np.ndarray:
        """The discrepancy ``g`` of channel ``name`` at standardised ``phi`` (F,) or (N, F)
        [unit]."""
        ch = self.channel(name)
        return ch.intercept + np.asarray(phi, float) @ np.asarray(ch.coef, float)

    def offset_var(self, name: str, phi: np.ndarray) -> np.ndarray:
        """Variance of ``g`` at ``phi`` from the coefficients' uncertainty [unit^2]."""
        phi = np.asarray(phi, float)
        return np.einsum("...i,ij,...j->...", phi, self.channel(name).cov, phi)

    def to_table(self) -> dict[str, Any]:
        """The TOML table (inverse of :func:`model_error_of`)."""
        d = asdict(self)
        for k in ("features", "mean", "scale"):
            d[k] = list(d[k])
        for name in CHANNELS:
            d[name]["coef"] = list(d[name]["coef"])
            d[name]["coef_cov"] = list(d[name]["coef_cov"])
        d["day_cov"] = list(d["day_cov"])
        return d


def model_error_from_table(table: Any, source: str) -> ModelError:
    """Build (and validate) a :class:`ModelError` from its TOML table; a one-line
    :class:`ConfigError` naming ``model_error.<key>`` otherwise."""
    return build_section(ModelError, table, "model_error", source)


def model_error_of(config: PlantConfig) -> ModelError | None:
    """The ``[model_error]`` a PARAMS.toml gave ``config`` (``None`` without one), built once
    (:func:`~softsensor.plantconfig.built_table`)."""
    return built_table(config, "model_error", _model_error)


def _model_error(config: PlantConfig) -> ModelError | None:
    table = config.extra.get("model_error")
    if table is None or isinstance(table, ModelError):
        return table
    return model_error_from_table(table, config.source)


def no_model_error(features: tuple[str, ...], mean: np.ndarray, scale: np.ndarray) -> ModelError:
    """A :class:`ModelError` that changes nothing (zero discrepancy, zero offsets); the
    features as given. For tests and as the neutral element."""
    n = len(features)
    zero = ChannelError(coef=(0.0,) * n, coef_cov=(0.0,) * (n * n), intercept=0.0, day_sd=0.0,
                        walk=0.0, noise=0.0, rmse_without=0.0, rmse_held_out=0.0, samples=0)
    if len(mean) != n or len(scale) != n:
        raise ConfigError("no_model_error: mean and scale must match the features")
    return ModelError(features=tuple(features), mean=tuple(map(float, mean)),
                      scale=tuple(map(float, scale)), T_dryer_out=zero, T_cyclone_out=zero,
                      moisture_out=zero)


__all__ = ["CHANNELS", "FEATURES", "ChannelError", "ModelError", "model_error_from_table",
           "model_error_of", "no_model_error"]
