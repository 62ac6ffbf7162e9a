"""The one place the service builds an estimator from its kind name.

``make_estimator("ukf", cfg)`` (the default) builds the unscented Kalman filter of
:mod:`softsensor.estimation.ukf`, ``make_estimator("openloop", cfg)`` the calibrated model run
open loop (:mod:`softsensor.estimation.open_loop_estimator`). Both take the plant config with
calibrated parameter values (apply a ``PARAMS.toml`` with
:func:`softsensor.plantconfig.load_parameters` first) and read their tuning from its optional
``[estimator]`` table.
"""

from __future__ import annotations

from collections.abc import Callable

from softsensor.errors import ConfigError
from softsensor.estimation.interface import Estimator
from softsensor.estimation.settings import ESTIMATOR_KINDS, estimator_settings
from softsensor.plantconfig import PlantConfig


def _ukf(cfg: PlantConfig) -> Estimator:
    from softsensor.estimation.ukf import UkfEstimator
    return UkfEstimator(cfg)


def _openloop(cfg: PlantConfig) -> Estimator:
    from softsensor.estimation.open_loop_estimator import OpenLoopEstimator
    return OpenLoopEstimator(cfg)


_BUILDERS: dict[str, Callable[[PlantConfig], Estimator]] = {"ukf": _ukf, "openloop": _openloop}
assert set(_BUILDERS) == set(ESTIMATOR_KINDS)


def default_kind(cfg: PlantConfig) -> str:
    """The config's ``estimator.kind`` (``ukf`` when the table is absent)."""
    return estimator_settings(cfg).kind


def make_estimator(kind: str | None, cfg: PlantConfig) -> Estimator:
    """Build the estimator ``kind`` (None: the config's default) for the plant ``cfg``.

    Raises :class:`~softsensor.errors.ConfigError` naming the kind when it is unknown.
    """
    kind = default_kind(cfg) if kind is None else kind
    builder = _BUILDERS.get(kind)
    if builder is None:
        raise ConfigError(f"estimator {kind!r} is not known (choose {', '.join(_BUILDERS)})")
    return builder(cfg)


def estimator_kind(estimator: Estimator) -> str:
    """Kind name of a built estimator (its ``kind`` attribute, else the class name)."""
    return str(getattr(estimator, "kind", type(estimator).__name__))


__all__ = ["ESTIMATOR_KINDS", "default_kind", "estimator_kind", "make_estimator"]
