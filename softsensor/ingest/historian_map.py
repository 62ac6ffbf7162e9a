"""The historian map: which column or tag of a historian export and a LIMS file is which signal.

A TOML file with one section per dataclass (see ``replay/historian-map.toml``)::

    [source]                         # -> SourceMap: the historian export
    layout = "wide"                  # "wide": one column per tag; "long": time, tag, value
    time_column = "Timestamp"
    time_zone = "Europe/Stockholm"   # IANA name; naive timestamps are read in it (with DST)
    time_unit = "s"                  # only for numeric timestamps: s, ms, us or ns since epoch
    time_format = "%d.%m.%Y %H:%M"   # optional strftime format (default ISO-8601)
    tag_column = "Tag"               # long layout: the tag name ...
    value_column = "Value"           # ... its value ...
    quality_column = "Quality"       # ... and its quality (optional)
    good_quality = ["Good", "192"]   # quality strings that mean good (case-insensitive)
    bad_values = ["Calc Failed"]     # more bad-value strings than the built-in ones
    delimiter = ","                  # CSV only
    decimal = "."                    # CSV only: "," for a decimal comma

    [signals.T_air_in]               # -> SignalMap, one per scan signal (CONTRACT section 1)
    column = "TI-101.PV"             # wide layout: the column; long layout: tag = "TI-101.PV"
    unit = "degC"                    # any unit pint knows that converts to the signal's SI unit
    quality_column = "TI-101.Q"      # wide layout, optional

    [signals.H_amb]
    constant = 0.008                 # a signal the plant does not record: one value, SI unit
    unit = "kg/kg"

    [lab]                            # -> LabMap: the LIMS file (optional)
    sample_time_column = "SampleTime"
    moisture_column = "Moisture"
    unit = "%"                       # %, kg/kg, g/kg
    basis = "wet"                    # wet: w = water / wet mass, converted to X = w / (1 - w)
    sample_id_column = "SampleID"
    available_column = "ResultTime"  # when the result became available, or:
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

from softsensor.configfile import build_section, num, read_toml
from softsensor.errors import ConfigError
from softsensor.ingest.units import check_unit, signal_target
from softsensor.signals import SCAN_SIGNALS

#: Timestamp units of numeric timestamps and their size [ns].
TIME_UNITS: dict[str, int] = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}
LAYOUTS: tuple[str, ...] = ("wide", "long")
BASES: tuple[str, ...] = ("wet", "dry")

#: Value strings that historians write for a value they could not read (PI digital states,
#: OPC and spreadsheet spellings); matched case-insensitively after trimming.
DEFAULT_BAD_VALUES: tuple[str, ...] = (
    "Bad", "Bad Input", "Bad Quality", "Bad Data", "I/O Timeout", "Shutdown", "Comm Fail",
    "No Data", "Calc Failed", "Scan Off", "Scan Timeout", "Not Connect", "Out of Serv",
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
        if self.decimal not in (".", ","):
            return f"decimal must be '.' or ',', got {self.decimal!r}"
        if len(self.delimiter) != 1:
            return f"delimiter must be one character, got {self.delimiter!r}"
        return (_zone_problem("time_zone", self.time_zone)
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

    def check(self) -> str | None:
        given = [k for k in ("column", "tag", "constant") if getattr(self, k) is not None]
        if len(given) != 1:
            return ("needs exactly one of column (wide layout), tag (long layout) or constant, "
                    f"got {', '.join(given) or 'none'}")
        return None


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

    def check(self) -> str | None:
        if self.basis not in BASES:
            return f"basis must be 'wet' or 'dry', got {self.basis!r}"
        if (self.available_column is None) == (self.delay_min is None):
            return ("needs exactly one of available_column (when the result became available) "
                    "or delay_min (sample time plus a delay)")
        if self.decimal not in (".", ","):
            return f"decimal must be '.' or ',', got {self.decimal!r}"
        return (_zone_problem("time_zone", self.time_zone)
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
            check_unit(sm.unit, signal_target(name), f"{key}.unit")
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        signals[name] = sm
    lab = None
    if "lab" in doc:
        lab = build_section(LabMap, doc["lab"], "lab", where)
        try:
            check_unit(lab.unit, "dimensionless", "lab.unit")
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
    return HistorianMap(path=path or Path(where), source=source, signals=signals, lab=lab)


def load_map(path: str | Path) -> HistorianMap:
    """Read and validate a historian map TOML file."""
    p = Path(path)
    return build_map(read_toml(p), str(p), p)
