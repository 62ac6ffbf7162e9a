"""What people read: plant units and local clock time (the ``[display]`` table).

The program computes in SI (K, kg/kg dry basis, ns since the epoch, UTC) and keeps SI in every
file and message other programs read (docs/interface.md). Summaries, report pages, figures and
the daemon's operator outputs show °C, moisture in % on the basis the plant's lab uses, and the
plant's local clock time instead.

Example ``config/dryer1.toml`` fragment::

    [display]
    time_zone = "Europe/Stockholm"   # IANA name; figure axes and report times in it
    moisture_basis = "wet"           # "wet": w = X / (1 + X) in %; "dry": X in %
    moisture_target = 0.10           # outlet moisture target [kg/kg dry basis], drawn ...
    moisture_low = 0.06              # ... with the acceptable band (CONTRACT section 6)
    moisture_high = 0.16

Every human output reads this one table: the daemon's log lines, the live page, report pages
and figures, verdicts, ``import`` and ``export`` summaries, ``export --local-time
--moisture-percent`` tables.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of

MOISTURE_BASES: tuple[str, ...] = ("wet", "dry")
#: 0 °C in kelvin [K].
C0 = 273.15
def moisture_band(x: Any, sd: Any, z: float = 1.96) -> tuple[Any, Any]:
    """The band ``x -+ z sd`` of a dry-basis moisture [kg/kg], its low end clipped at 0: no
    fibre is drier than bone dry (the start-up band ran the page's axis to -10 % wb). Numbers
    or numpy arrays; NaN stays NaN."""
    low = np.asarray(x, dtype=float) - z * np.asarray(sd, dtype=float)
    high = np.asarray(x, dtype=float) + z * np.asarray(sd, dtype=float)
    low = np.where(low < 0.0, 0.0, low)
    if np.ndim(low) == 0:
        return float(low), float(high)
    return low, high


#: A mass flow of 1 kg/s in t/h (what a plant's flow meters and operators read).
T_H_PER_KG_S = 3.6


@dataclass(frozen=True)
class DisplaySettings:
    """The ``[display]`` table (module docstring).

    Attributes
    ----------
    time_zone : str
        IANA time zone of the plant's clock (``UTC`` by default).
    moisture_basis : str
        ``wet`` (% of the wet mass, what most labs report) or ``dry`` (% of the dry mass).
    moisture_target, moisture_low, moisture_high : float
        The outlet moisture target and its acceptable band [kg/kg dry basis, as every
        moisture in a config]; pages and dashboards draw them in % on ``moisture_basis``.
    """

    time_zone: str = "UTC"
    moisture_basis: str = "wet"
    moisture_target: float = num(0.10, gt=0, le=2)  #: [kg/kg dry] CONTRACT section 6
    moisture_low: float = num(0.06, gt=0, le=2)  #: acceptable band [kg/kg dry]
    moisture_high: float = num(0.16, gt=0, le=2)

    def check(self) -> str | None:
        if not self.moisture_low < self.moisture_target < self.moisture_high:
            return (f"moisture_target must lie inside moisture_low..moisture_high, got "
                    f"{self.moisture_target} not in {self.moisture_low}..{self.moisture_high}")
        if self.moisture_basis not in MOISTURE_BASES:
            return (f"moisture_basis must be one of {', '.join(MOISTURE_BASES)}, "
                    f"got {self.moisture_basis!r}")
        try:
            ZoneInfo(self.time_zone)
        except (ZoneInfoNotFoundError, ValueError):
            return f"time_zone {self.time_zone!r} is not an IANA time zone (e.g. Europe/Berlin)"
        return None

    @property
    def zone(self) -> ZoneInfo:
        return ZoneInfo(self.time_zone)

    @property
    def moisture_unit(self) -> str:
        """``% wb`` or ``% db``: the label of a moisture shown in this basis."""
        return f"% {self.moisture_basis[0]}b"


def display_settings(cfg: PlantConfig) -> DisplaySettings:
    """The validated ``[display]`` table of ``cfg`` (built once; UTC and wet basis when
    absent)."""
    return section_of(cfg, "display", DisplaySettings)


def moisture_pct(x: float | np.ndarray, basis: str = "wet") -> float | np.ndarray:
    """Dry-basis moisture ``X`` [kg/kg] in % on ``basis``: 100 X / (1 + X) wet, 100 X dry."""
    if basis not in MOISTURE_BASES:
        raise ValueError(f"moisture basis must be one of {MOISTURE_BASES}, got {basis!r}")
    x = np.asarray(x, dtype=float)
    return 100.0 * (x / (1.0 + x) if basis == "wet" else x)


def moisture_pct_points(dx: float, x: float, basis: str = "wet") -> float:
    """A dry-basis moisture difference ``dx`` [kg/kg] near ``x`` as % points on ``basis``."""
    return float(moisture_pct(x + dx, basis) - moisture_pct(x, basis))


def lab_reference(segments) -> float:
    """The moisture [kg/kg dry] at which kg/kg errors become % points: the median lab result
    of ``segments`` (anything with ``lab_value``), 0.1 without one."""
    labs = np.concatenate([seg.lab_value for seg in segments]) if segments else np.zeros(0)
    return float(np.median(labs)) if labs.size else 0.1


def plant_error(name: str, value: float, x_ref: float, settings: DisplaySettings
                ) -> tuple[float, str]:
    """An error (RMSE, offset) of the output channel ``name`` in what people read: a kelvin
    difference is the same number of °C; a moisture difference [kg/kg dry] near ``x_ref``
    becomes % points on the display basis. Returns the value and its unit."""
    if name.startswith("moisture"):
        basis = settings.moisture_basis
        return moisture_pct_points(value, x_ref, basis), f"% points ({basis} basis)"
    return float(value), "°C"


def celsius(T: float | np.ndarray) -> float | np.ndarray:
    """Temperature [K] in °C."""
    return T - C0


def local_times(time_ns: np.ndarray, settings: DisplaySettings) -> np.ndarray:
    """Times [ns since the epoch, UTC] as timezone-aware datetimes of the plant's clock (an
    object array matplotlib plots on a date axis)."""
    from datetime import UTC, datetime

    zone = settings.zone
    return np.array([datetime.fromtimestamp(int(t) / 1e9, UTC).astimezone(zone)
                     for t in np.asarray(time_ns).ravel()], dtype=object)


def local_clock(time_ns: int, settings: DisplaySettings) -> str:
    """A time [ns since the epoch] as the plant's clock reads it, ISO-8601 with its offset
    (``2026-01-05T13:20:00+01:00``)."""
    return local_times(np.array([time_ns]), settings)[0].isoformat(timespec="seconds")


__all__ = ["C0", "MOISTURE_BASES", "T_H_PER_KG_S", "DisplaySettings", "celsius", "lab_reference",
           "display_settings", "local_clock", "local_times", "moisture_band", "moisture_pct",
           "moisture_pct_points", "plant_error"]
