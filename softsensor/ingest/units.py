"""Plant units to the contract's SI units (CONTRACT section 1), through pint.

Historians and laboratories write what a person reads (°C, degF, t/h, kg/h, %, g/kg); every
message the project writes is SI (K, kg/s, kg/kg, flap in %). Units are parsed by pint (one
registry, created once), so any unit pint knows is accepted and a unit of the wrong kind (a
temperature for a flow) is refused instead of scaled by a guessed factor.
"""

from __future__ import annotations

import functools

import numpy as np
import pint

from softsensor.errors import ConfigError
from softsensor.signals import SCAN_SIGNALS

#: pint spelling of the SI unit of each scan signal (CONTRACT section 1).
PINT_SI: dict[str, str] = {"K": "kelvin", "kg/s": "kg/s", "kg/kg": "dimensionless",
                           "%": "percent"}

#: Physical range of each scan signal [SI]: CONTRACT section 6's operating envelope of dryer1
#: widened to what the instrument can read at all (a stopped dryer in winter, a flow meter's
#: small negative zero), so that only a wrong unit or a broken instrument falls outside. Each
#: bound also catches the usual unit slips: °C read as K (T < 230 K), t/h as kg/s (m_fiber
#: 21.6, m_air 295), kg/h as t/h (m_steam 1800 t/h), relative humidity or g/kg as a humidity
#: ratio (H_amb 0.9 or 9 kg/kg).
PHYSICAL_RANGE: dict[str, tuple[float, float]] = {
    "T_air_in": (230.0, 900.0),      # envelope 440..560 K; cold when the burner is off
    "m_air": (-2.0, 200.0),          # envelope 82 kg/s +-10 %
    "m_fiber": (-0.5, 20.0),         # envelope 4.5..7.0 kg/s
    "T_fiber_in": (230.0, 450.0),    # about 370 K
    "m_steam": (-0.2, 5.0),          # about 0.5 kg/s
    "T_amb": (220.0, 330.0),         # envelope 255..310 K
    "H_amb": (0.0, 0.05),            # envelope 0.001..0.02 kg/kg; saturated at 40 °C: 0.049
    "flap_cmd": (-5.0, 105.0),       # a PID output 0..100 %
    "T_sp": (230.0, 500.0),          # nominal 348 K
    "T_dryer_out": (230.0, 500.0),   # near T_sp
    "T_cyclone_out": (230.0, 500.0),  # a few K below T_dryer_out
}


@functools.cache
def registry() -> pint.UnitRegistry:
    """The one pint registry (building it takes a few tenths of a second)."""
    return pint.UnitRegistry()


def check_unit(unit: str, target: str, key: str) -> None:
    """Raise :class:`ConfigError` naming ``key`` unless ``unit`` converts to ``target``."""
    ureg = registry()
    try:
        ureg.Quantity(1.0, unit).to(target)
    except pint.UndefinedUnitError as exc:
        raise ConfigError(f"{key} {unit!r} is not a unit pint knows "
                          "(e.g. degC, degF, K, t/h, kg/h, kg/s, %, g/kg)") from exc
    except pint.DimensionalityError as exc:
        raise ConfigError(f"{key} {unit!r} cannot be converted to {target}") from exc
    except (pint.PintError, AttributeError, TypeError, ValueError) as exc:
        raise ConfigError(f"{key} {unit!r} is not a unit pint can parse ({exc})") from exc


def quantity_si(text: str, target: str, key: str) -> float:
    """A quantity written with its unit (``"1013 hPa"``, ``"1 atm"``) in ``target``;
    :class:`ConfigError` naming ``key`` when it is not one."""
    try:
        q = registry().Quantity(text)
        return float(q.to(target).magnitude)
    except pint.DimensionalityError as exc:
        raise ConfigError(f"{key} {text!r} cannot be converted to {target}") from exc
    except (pint.PintError, AttributeError, TypeError, ValueError) as exc:
        raise ConfigError(f"{key} {text!r} is not a quantity with a unit pint knows "
                          "(e.g. '1013 hPa', '101.3 kPa', '1 atm')") from exc


def to_unit(values: np.ndarray, unit: str, target: str) -> np.ndarray:
    """``values`` given in ``unit`` expressed in ``target`` (offsets such as °C handled)."""
    if unit == target:
        return np.asarray(values, dtype=float)
    q = registry().Quantity(np.asarray(values, dtype=float), unit)
    return np.asarray(q.to(target).magnitude, dtype=float)


def signal_target(signal: str) -> str:
    """pint spelling of the SI unit of the scan signal ``signal``."""
    return PINT_SI[SCAN_SIGNALS[signal]]


def to_signal_si(values: np.ndarray, unit: str, signal: str) -> np.ndarray:
    """``values`` of ``signal`` given in ``unit``, in the signal's SI unit."""
    return to_unit(values, unit, signal_target(signal))


def moisture_dry_basis(values: np.ndarray, unit: str, basis: str) -> np.ndarray:
    """Moisture in ``unit`` (%, kg/kg, g/kg) on ``basis`` (wet/dry) as dry basis [kg/kg].

    Wet basis w (water per wet mass) is dry basis X = w / (1 - w) (water per dry mass); a wet
    basis of 1 or more has no dry mass and gives NaN.
    """
    frac = to_unit(values, unit, "dimensionless")
    if basis == "dry":
        return frac
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(frac < 1.0, frac / (1.0 - frac), np.nan)
