"""The library of structural alternatives: the model's shapes that no multiplier can change.

A Table 1 multiplier scales a rate; it does not change how steeply the outlet moisture answers
the inlet air temperature near the end of drying (issue 29). Where published drying physics
differs, the model offers alternatives, each selected purely by plant-config keys (compiled
in, dispatched per plant inside the kernels, no Python branching per cell):
:func:`structure_space` lists them as data, one :class:`Alternative` each, for a structural
search to calibrate and judge; :func:`alternative_config` turns one (with values for its free
keys) into a checked :class:`~softsensor.plantconfig.PlantConfig` through
:meth:`~softsensor.plantconfig.PlantConfig.with_keys`, and :func:`commission` scales its rate
multipliers to the configured model's nominal outlet moisture.

Alternatives of one ``family`` exclude each other (one drying law); alternatives of different
families combine (a drying law with a cyclone hold-up). The paper's form is each family's
default and keeps the model bit for bit as it was (``tests/model/test_model_digest.py``).

Commissioning
-------------
The paper's double sigmoid falls to ``bound_fraction`` (0.00135) of the free-water rate below
the critical moisture, and the nominal inlet (1.0 kg/kg) is already below it (1.25 kg/kg);
Keey's curve and Chen's approach leave the rate within a factor of a few of the free-water
rate there. So an alternative law reaches the paper's nominal outlet moisture only with the
drying multipliers ``mult_D`` and ``mult_C`` scaled down together by a factor ``k`` (measured
at the nominal point with the default shape parameters, ``tests/model/test_drying_laws.py``):
``k = 0.0120`` for ``cdc`` (``n = 1``) and ``0.00591`` for ``rea`` (``b = 5``, ``c = 1``);
``k`` grows steeply with ``n`` (0.145 at ``n = 2``, 2.0 at ``n = 3``; beyond 3 no ``mult_D``
within Table 1's 5 reaches it). Each alternative therefore carries the Table 1 values it is
commissioned with and bounds that reach down to 1e-4 (:attr:`Alternative.parameters`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy.optimize import brentq

from softsensor.errors import ConfigError, SolverError
from softsensor.model.dryer import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig


@dataclass(frozen=True)
class KeyRange:
    """A free key of an alternative: its search bounds, default and scale.

    ``low``/``high`` are the bounds a search should use; the config's own validation bounds
    (:class:`~softsensor.plantconfig.Fiber`) are as wide or wider. ``default`` is the shipped
    config's value (``config/dryer1.toml``) or the key's default.
    """

    key: str        # dotted plant-config key, e.g. "fiber.cdc_exponent"
    default: float
    low: float
    high: float
    log: bool
    unit: str


@dataclass(frozen=True)
class Alternative:
    """One structural alternative (module notes).

    Attributes
    ----------
    name : str
        Unique name, e.g. ``"drying_law.cdc"``.
    family : str
        The structural choice it belongs to; one alternative per family at a time.
    sets : mapping
        Keys fixed by choosing it (``{"fiber.drying_law": "cdc"}``), dotted as in the TOML.
    free : tuple of KeyRange
        Shape parameters a search calibrates within their bounds (defaults: the config's).
    parameters : mapping
        Table 1 parameters the alternative is commissioned with: ``name -> (value, low,
        high)`` (empty: the config's own).
    source : str
        The published law.
    default : bool
        Whether this is the paper's form (the config's default).
    """

    name: str
    family: str
    sets: Mapping[str, Any]
    free: tuple[KeyRange, ...]
    source: str
    parameters: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    default: bool = False

    def __post_init__(self) -> None:
        # the library is shared data: its mappings read-only, as the dataclass is frozen
        object.__setattr__(self, "sets", MappingProxyType(dict(self.sets)))
        object.__setattr__(self, "parameters", MappingProxyType(dict(self.parameters)))


#: Bounds of the drying multipliers of a commissioned alternative law (module notes).
_RATE_LOW, _RATE_HIGH = 1e-4, 5.0

_CRITICAL = KeyRange("fiber.critical_moisture", 1.25, 0.8, 2.0, False, "kg/kg")

_SPACE: tuple[Alternative, ...] = (
    Alternative(
        name="drying_law.double_sigmoid", family="drying_law",
        sets={"fiber.drying_law": "double_sigmoid"},
        free=(_CRITICAL,
              KeyRange("fiber.critical_width", 0.12, 0.03, 0.5, True, "kg/kg"),
              KeyRange("fiber.bound_fraction", 0.00135, 1e-4, 2e-2, True, "-"),
              KeyRange("fiber.equilibrium_width", 0.10, 0.02, 0.3, True, "kg/kg")),
        source="the paper's eq. 2 double sigmoid after Pang (2001); critical moisture of "
               "spruce MDF fibre from Fritzell et al. (2009)",
        default=True),
    Alternative(
        name="drying_law.cdc", family="drying_law",
        sets={"fiber.drying_law": "cdc"},
        free=(KeyRange("fiber.cdc_exponent", 1.0, 1.0, 3.0, False, "-"), _CRITICAL),
        parameters={"mult_D": (0.01203, _RATE_LOW, _RATE_HIGH),
                    "mult_C": (0.003008, _RATE_LOW, _RATE_HIGH)},
        source="Keey (1992), Drying of Loose and Particulate Materials, Hemisphere: the "
               "characteristic drying curve f = ((X - X_eq) / (X_cr - X_eq))^n"),
    Alternative(
        name="drying_law.rea", family="drying_law",
        sets={"fiber.drying_law": "rea"},
        free=(KeyRange("fiber.rea_b", 5.0, 0.5, 100.0, True, "(kg/kg)^-c"),
              KeyRange("fiber.rea_c", 1.0, 1.0, 3.0, False, "-")),
        parameters={"mult_D": (0.005913, _RATE_LOW, _RATE_HIGH),
                    "mult_C": (0.001481, _RATE_LOW, _RATE_HIGH)},
        source="Chen & Xie (1997), Food Res. Int. 30:429; Chen (2008), Drying Technol. "
               "26:627: the reaction engineering approach, dE_v / dE_v,inf = "
               "exp(-b (X - X_eq)^c)"),
    Alternative(
        name="cyclone.hold_up", family="cyclone_hold_up",
        sets={},
        free=(KeyRange("cyclone.hold_up_time", 4.0, 1.0, 30.0, True, "s"),),
        source="the paper's section 2.2 (fibre separated and held up for seconds; eq. 3's "
               "lumped cyclone read with the fibre surface a_s m_f tau_hold)",
        default=True),
    Alternative(
        name="heat_loss.ambient", family="heat_loss",
        sets={},
        free=(KeyRange("environment.wind_speed", 2.0, 0.0, 10.0, False, "m/s"),
              KeyRange("environment.ambient_loss_slope", 0.0, -0.1, 0.6, False, "1/K")),
        source="outside coefficient: Churchill & Bernstein (1977) forced convection across "
               "the tube in the configured wind, Churchill & Chu (1975) natural convection "
               "and grey-body radiation (transfer.outside_coefficient); the ambient slope "
               "is the diagnosis's ambient_heat_loss law (1 + beta (283.15 K - T_amb)) "
               "made a plant constant",
        default=True),
)


def structure_space() -> tuple[Alternative, ...]:
    """Every structural alternative of the model (module notes), the paper's forms first in
    each family. Pure data: build a config with :func:`alternative_config`."""
    return _SPACE


def alternative_config(cfg: PlantConfig, alternative: Alternative,
                       values: Mapping[str, float] | None = None) -> PlantConfig:
    """``cfg`` with ``alternative`` chosen: its fixed keys, its free keys at ``values`` (by
    dotted key; the others as ``cfg`` has them) and its commissioned Table 1 parameters
    (value and bounds; a search starts there).

    Raises :class:`~softsensor.errors.ConfigError` (one line naming the dotted key) for a
    value outside the config's bounds or a key the alternative does not have.
    """
    values = dict(values or {})
    free = [r.key for r in alternative.free]
    unknown = sorted(set(values) - set(free))
    if unknown:
        raise ConfigError(f"{cfg.source}: {unknown[0]} is not a free key of "
                          f"{alternative.name} (free: {', '.join(free) or 'none'})")
    keys: dict[str, Any] = {**alternative.sets, **values}
    for name, (value, low, high) in alternative.parameters.items():
        keys[f"parameters.{name}.value"] = value
        keys[f"parameters.{name}.low"] = low
        keys[f"parameters.{name}.high"] = high
    return cfg.with_keys(keys)


def commission(cfg: PlantConfig, alternative: Alternative,
               values: Mapping[str, float] | None = None,
               target: float | None = None) -> PlantConfig:
    """:func:`alternative_config` with ``mult_D`` and ``mult_C`` scaled together (their ratio
    as commissioned) so that the steady ``moisture_out`` at ``cfg``'s nominal point equals
    ``target`` (default: ``cfg``'s own, the model as configured): the start a search needs
    when the free keys move the rate's level (module notes; ``cdc_exponent`` 2 needs 12 times
    the commissioned scale). An alternative without commissioned parameters is returned as
    :func:`alternative_config` gives it.

    Raises
    ------
    softsensor.errors.SolverError
        When no scale within the alternative's bounds reaches ``target``.
    """
    out = alternative_config(cfg, alternative, values)
    if "mult_D" not in alternative.parameters:
        return out
    if target is None:
        ref = DryerModel(cfg, threads=1)
        target = float(ref.steady_state(ref.nominal_inputs(), ref.theta0)[1][2])
    model = DryerModel(out, threads=1)
    u = model.nominal_inputs()
    names = [n for n in ("mult_D", "mult_C") if n in alternative.parameters]
    start = {n: alternative.parameters[n][0] for n in names}
    low = max(alternative.parameters[n][1] / start[n] for n in names)
    high = min(alternative.parameters[n][2] / start[n] for n in names)

    def miss(log_k: float) -> float:
        theta = model.theta0.copy()
        for n in names:
            theta[PARAMETER_NAMES.index(n)] = start[n] * np.exp(log_k)
        return float(model.steady_state(u, theta)[1][2]) - target

    lo, hi = np.log(low), np.log(high)
    if miss(lo) * miss(hi) > 0.0:
        raise SolverError(f"{alternative.name} with {dict(values or {})}: no scale of "
                          f"{' and '.join(names)} within their bounds reaches moisture_out "
                          f"{target:.4f} kg/kg at the nominal point")
    k = float(np.exp(brentq(miss, lo, hi, xtol=1e-8)))
    return out.with_parameters({n: start[n] * k for n in names})
