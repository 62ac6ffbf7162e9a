"""The historian map: which column or tag of a historian export and a LIMS file is which signal.

A TOML file with one section per dataclass; every key, its default and an example of a PI
style export are in ``docs/historian-map.md`` (the reference a plant engineer reads; a test
checks it names every field below). In short::

    [source]                         # -> SourceMap: the historian export
    layout = "wide"                  # "wide": one column per tag; "long": time, tag, value
    time_column = "Timestamp"
    time_zone = "Europe/Madrid"      # IANA name; naive timestamps are read in it (with DST)
    dayfirst = true                  # 07/05/2026 is 7 May (when no time_format is given)
    skip_rows = 1                    # rows under the header that are not data (units row)
    decimal = ","                    # CSV only: decimal comma ...
    thousands = "."                  # ... and thousands separator

    [signals.T_air_in]               # -> SignalMap, one per scan signal (CONTRACT section 1)
    column = "TI-4711.PV"            # wide layout: the column; long layout: tag = "..."
    unit = "degC"                    # any unit pint knows that converts to the signal's SI unit

    [signals.H_amb]
    column = "MI-4720.PV"
    unit = "%"
    quantity = "relative_humidity"   # or "dew_point" (a temperature unit), "humidity_ratio"
    pressure = "1013 hPa"            # ambient pressure of the conversion (default 1 atm)

    [lab]                            # -> LabMap: the LIMS file (optional); the daemon's lab
    sample_time_column = "SampleTime"  # folder reads the same table from the plant config
    moisture_column = "Moisture"
    unit = "%"                       # %, kg/kg, g/kg
    basis = "wet"                    # wet: w = water / wet mass, converted to X = w / (1 - w)
    sample_id_column = "SampleID"
    available_column = "ResultTime"  # when the result became available (import), or:
    delay_min = 45                   # sample time plus this delay

Every error is one line naming the file and the dotted key (:mod:`softsensor.configfile`).
A signal absent from the map is ``null`` in every scan (the import summary names it).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from softsensor.configfile import build_section, choice, num, read_toml
from softsensor.errors import ConfigError
from softsensor.ingest.humidity import HUMIDITY_QUANTITIES
from softsensor.ingest.units import check_unit, quantity_si, signal_target
from softsensor.plantconfig import PlantConfig, built_table
from softsensor.signals import SCAN_SIGNALS

#: Timestamp units of numeric timestamps and their size [ns].
TIME_UNITS: dict[str, int] = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}
LAYOUTS: tuple[str, ...] = ("wide", "long")
BASES: tuple[str, ...] = ("wet", "dry")

#: Value strings that historians write for a value they could not read (PI digital states,
#: OPC and spreadsheet spellings); matched case-insensitively after trimming.
DEFAULT_BAD_VALUES: tuple[str, ...] = (
    "Bad", "Bad Value", "Bad Val", "Bad Input", "Bad Output", "Bad Quality", "Bad Data",
    "Invalid Data", "No Good Data For Calculation", "No Sample", "Arc Off-line", "I/O Timeout",
    "Shutdown", "Comm Fail", "No Data", "Calc Failed", "Scan Off", "Scan Timeout", "Not Connect",
    "Out of Serv",
    "Over Range", "Under Range", "Intf Shut", "Configure", "Pt Created", "Error", "NaN",
    "null", "N/A", "#N/A",
)
#: Quality strings that mean good (PI "Good", OPC DA quality 192); an empty quality is good.
DEFAULT_GOOD_QUALITY: tuple[str, ...] = ("Good", "192")


def _zone_problem(field: str, name: str | None) -> str | None:
    if name is None:
        return None
    try:
        ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError):
        return f"{field} {name!r} is not an IANA time zone name (e.g. 'Europe/Stockholm', 'UTC')"
    return None


def _unit_problem(field: str, unit: str | None) -> str | None:
    if unit is not None and unit not in TIME_UNITS:
        return f"{field} must be one of {', '.join(TIME_UNITS)}, got {unit!r}"
    return None


#: Most rows of an export read by default (a year of one-minute rows in the wide layout is
#: 525,600); ``source.max_rows`` raises it knowingly (memory grows with it).
DEFAULT_MAX_ROWS = 1_000_000
#: What a value outside a signal's physical range does: stop the import, or become null.
OUT_OF_RANGE: tuple[str, ...] = ("refuse", "null")


def _csv_problem(delimiter: str, decimal: str, thousands: str | None) -> str | None:
    if decimal not in (".", ","):
        return f"decimal must be '.' or ',', got {decimal!r}"
    if len(delimiter) != 1:
        return f"delimiter must be one character, got {delimiter!r}"
    if thousands is not None and (len(thousands) != 1 or thousands.isdigit()
                                  or thousands in (decimal, delimiter)):
        return (f"thousands must be one character other than a digit, the decimal mark and "
                f"the delimiter, got {thousands!r}")
    return None


def _strings_problem(field: str, value: Any) -> str | None:
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        return f"{field} must be a list of non-empty strings, got {value!r}"
    return None


@dataclass(frozen=True)
class SourceMap:
    """Section ``[source]``: layout and time column of the historian export."""

    layout: str  #: "wide" (one column per tag) or "long" (time, tag, value rows)
    time_column: str  #: column of the timestamps
    time_zone: str | None = None  #: IANA zone of naive timestamps (required if they are naive)
    time_unit: str | None = None  #: unit of numeric timestamps since the epoch: s, ms, us, ns
    time_format: str | None = None  #: strftime format of text timestamps (default ISO-8601)
    tag_column: str | None = None  #: long layout: column of the tag names
    value_column: str | None = None  #: long layout: column of the values
    quality_column: str | None = None  #: long layout: column of the qualities (optional)
    good_quality: list[str] = dataclasses.field(
        default_factory=lambda: list(DEFAULT_GOOD_QUALITY))  #: qualities that mean good
    bad_values: list[str] = dataclasses.field(default_factory=list)  #: extra bad strings
    delimiter: str = ","  #: CSV field separator
    decimal: str = "."  #: CSV decimal mark ("." or ",")
    thousands: str | None = None  #: CSV thousands separator ("1.234,5" with decimal ",")
    skip_rows: int = num(0, ge=0, le=100)  #: rows under the header that are not data
    dayfirst: bool = False  #: text dates are day first (07/05/2026 = 7 May), no time_format
    max_rows: int = num(DEFAULT_MAX_ROWS, ge=1, le=50_000_000)  #: refused beyond, unread

    def check(self) -> str | None:
        if self.layout not in LAYOUTS:
            return f"layout must be 'wide' or 'long', got {self.layout!r}"
        if self.layout == "long":
            for name in ("tag_column", "value_column"):
                if getattr(self, name) is None:
                    return f"{name} is missing (the long layout needs it)"
        elif self.tag_column or self.value_column or self.quality_column:
            return ("tag_column, value_column and quality_column belong to the long layout "
                    "(wide: signals.<name>.quality_column)")
        return (_csv_problem(self.delimiter, self.decimal, self.thousands)
                or _zone_problem("time_zone", self.time_zone)
                or _unit_problem("time_unit", self.time_unit)
                or _strings_problem("good_quality", self.good_quality)
                or _strings_problem("bad_values", self.bad_values))


@dataclass(frozen=True)
class SignalMap:
    """Section ``[signals.<name>]``: where one scan signal is in the export, in which unit."""

    unit: str  #: unit of the export's values (or of ``constant``)
    column: str | None = None  #: wide layout: the column holding the signal
    tag: str | None = None  #: long layout: the tag name in ``source.tag_column``
    quality_column: str | None = None  #: wide layout: the column of its quality (optional)
    constant: float | None = None  #: a value for every scan, for a signal not recorded
    #: H_amb only: what the column holds (relative humidity needs T_amb in the map too)
    quantity: str = choice(HUMIDITY_QUANTITIES, "humidity_ratio")
    pressure: str = "1 atm"  #: H_amb only: ambient pressure of the humidity conversion
    #: a value outside the signal's physical range stops the import ("refuse") or is null
    out_of_range: str = choice(OUT_OF_RANGE, "refuse")

    def check(self) -> str | None:
        given = [k for k in ("column", "tag", "constant") if getattr(self, k) is not None]
        if len(given) != 1:
            return ("needs exactly one of column (wide layout), tag (long layout) or constant, "
                    f"got {', '.join(given) or 'none'}")
        return None

    @property
    def pressure_pa(self) -> float:
        """``pressure`` [Pa] (checked by :func:`build_map`)."""
        return quantity_si(self.pressure, "Pa", "pressure")


@dataclass(frozen=True)
class LabMap:
    """Section ``[lab]``: columns and moisture convention of the LIMS file."""

    sample_time_column: str  #: when the sample was taken
    moisture_column: str  #: the moisture result
    unit: str  #: "%", "kg/kg" or "g/kg"
    basis: str  #: "wet" (per wet mass) or "dry" (per dry mass)
    sample_id_column: str | None = None  #: sample id (default: made from the sample time)
    available_column: str | None = None  #: when the result became available, or ...
    delay_min: float | None = num(None, ge=0.0)  #: ... sample time plus this delay [min]
    time_zone: str | None = None  #: IANA zone of naive times (default: source.time_zone)
    time_unit: str | None = None  #: unit of numeric times: s, ms, us, ns
    time_format: str | None = None  #: strftime format of text times (default ISO-8601)
    delimiter: str = ","  #: CSV field separator
    decimal: str = "."  #: CSV decimal mark
    thousands: str | None = None  #: CSV thousands separator
    skip_rows: int = num(0, ge=0, le=100)  #: rows under the header that are not data
    dayfirst: bool = False  #: text dates are day first (07/05/2026 = 7 May)

    def check(self) -> str | None:
        if self.basis not in BASES:
            return f"basis must be 'wet' or 'dry', got {self.basis!r}"
        if self.available_column is not None and self.delay_min is not None:
            return ("takes one of available_column (when the result became available) "
                    "or delay_min (sample time plus a delay), not both")
        return (_csv_problem(self.delimiter, self.decimal, self.thousands)
                or _zone_problem("time_zone", self.time_zone)
                or _unit_problem("time_unit", self.time_unit))


@dataclass(frozen=True)
class HistorianMap:
    """A whole historian map file."""

    path: Path
    source: SourceMap
    signals: dict[str, SignalMap]
    lab: LabMap | None

    @property
    def unmapped(self) -> list[str]:
        """Scan signals the map does not name (null in every scan)."""
        return [s for s in SCAN_SIGNALS if s not in self.signals]


def _check_signal(name: str, sm: SignalMap, key: str) -> None:
    """The unit of a signal's values, and the humidity keys of ``H_amb`` only."""
    if name != "H_amb" and (sm.quantity != "humidity_ratio" or sm.pressure != "1 atm"):
        raise ConfigError(f"{key}: quantity and pressure belong to signals.H_amb only")
    target = {"humidity_ratio": signal_target(name), "relative_humidity": "dimensionless",
              "dew_point": "kelvin"}[sm.quantity]
    check_unit(sm.unit, target, f"{key}.unit")
    quantity_si(sm.pressure, "Pa", f"{key}.pressure")


def build_map(doc: dict[str, Any], where: str, path: Path | None = None) -> HistorianMap:
    """Validate a parsed map document; errors are one-line ConfigErrors naming ``where``."""
    unknown = sorted(set(doc) - {"source", "signals", "lab"})
    if unknown:
        raise ConfigError(f"{where}: {unknown[0]} is not a known section "
                          "(known: source, signals, lab)")
    if "source" not in doc:
        raise ConfigError(f"{where}: [source] is missing")
    source = build_section(SourceMap, doc["source"], "source", where)
    table = doc.get("signals")
    if not isinstance(table, dict) or not table:
        raise ConfigError(f"{where}: [signals.<name>] sections are missing "
                          f"(one per signal of {', '.join(SCAN_SIGNALS)})")
    signals: dict[str, SignalMap] = {}
    for name, sub in table.items():
        key = f"signals.{name}"
        if name not in SCAN_SIGNALS:
            raise ConfigError(f"{where}: {key} is not a scan signal "
                              f"(known: {', '.join(SCAN_SIGNALS)})")
        sm = build_section(SignalMap, sub, key, where)
        if source.layout == "wide" and sm.tag is not None:
            raise ConfigError(f"{where}: {key}.tag belongs to the long layout; "
                              "the wide layout names a column")
        if source.layout == "long" and (sm.column is not None or sm.quality_column):
            raise ConfigError(f"{where}: {key}.column belongs to the wide layout; "
                              "the long layout names a tag")
        try:
            _check_signal(name, sm, key)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        signals[name] = sm
    rh = signals.get("H_amb")
    if rh is not None and rh.quantity == "relative_humidity" and "T_amb" not in signals:
        raise ConfigError(f"{where}: signals.H_amb.quantity = 'relative_humidity' needs "
                          "signals.T_amb (the temperature the humidity is relative to)")
    lab = build_lab(doc["lab"], where) if "lab" in doc else None
    return HistorianMap(path=path or Path(where), source=source, signals=signals, lab=lab)


def build_lab(table: Any, where: str) -> LabMap:
    """The ``[lab]`` table of a historian map or of a plant config, validated."""
    lab = build_section(LabMap, table, "lab", where)
    try:
        check_unit(lab.unit, "dimensionless", "lab.unit")
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    return lab


#: The lab folder's format when the plant config has no ``[lab]`` table: the columns of the
#: bus body (docs/interface.md section 2), moisture in kg/kg on a dry basis, the sample time
#: ISO-8601 or ns since the epoch.
DEFAULT_LAB_MAP = LabMap(sample_time_column="sample_time", moisture_column="moisture_out",
                         unit="kg/kg", basis="dry", sample_id_column="sample_id",
                         time_unit="ns")


def plant_lab_map(cfg: PlantConfig) -> LabMap:
    """The lab files' format of a plant: its config's ``[lab]`` table (the keys of a
    historian map's ``[lab]``, so a LIMS file ``softsensor import`` reads is read by the
    daemon's lab folder too), else :data:`DEFAULT_LAB_MAP`; built once."""
    return built_table(cfg, "lab", _plant_lab_map)


def _plant_lab_map(cfg: PlantConfig) -> LabMap:
    table = cfg.extra.get("lab")
    return DEFAULT_LAB_MAP if table is None else build_lab(table, cfg.source)


def load_map(path: str | Path) -> HistorianMap:
    """Read and validate a historian map TOML file."""
    p = Path(path)
    return build_map(read_toml(p), str(p), p)
