"""The Modbus tag map: where each scan signal lives in the PLC and how to read it.

A tag map is a TOML file with two sections (see ``config/tagmap_dryer1.toml``)::

    [modbus]                      # -> ModbusSettings
    host = "127.0.0.1"
    port = 502
    poll_period_s = 10.0          # optional, these are the defaults
    timeout_s = 1.0
    retries = 1
    reconnect_delay_s = 1.0
    reconnect_delay_max_s = 30.0
    frozen_after_s = 300.0
    max_gap_registers = 4
    max_registers_per_read = 125

    [tags.T_air_in]               # -> TagSpec, one per scan signal (CONTRACT section 1)
    unit_id = 1
    table = "input"               # "holding" (FC 3) or "input" (FC 4)
    address = 0                   # 0-based PDU address
    type = "float32"              # int16 uint16 int32 uint32 float32 float64
    word_order = "big"            # optional, default "big"
    byte_order = "big"            # optional, default "big"
    scale = 1.0                   # optional: eng = raw * scale + offset
    offset = 0.0                  # optional
    unit = "degC"                 # engineering unit, converted to the signal's SI unit
    valid_min = 300.0             # valid range, in SI units
    valid_max = 700.0
    frozen_after_s = 0            # optional per-tag override; 0 disables the frozen check

Loaded once into frozen dataclasses and validated; unknown keys, unknown signals and bad values
raise :class:`~softsensor.errors.ConfigError` with one line naming the file and the dotted key.
A tag map may hold a subset of the scan signals (the scan body then carries that subset).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from softsensor.errors import ConfigError
from softsensor.ingest.registers import DATA_TYPES, ORDERS, UNITS
from softsensor.signals import SCAN_SIGNALS

#: The reference tag map, shipped in the package (a copy of config/tagmap_dryer1.toml).
DEFAULT_TAGMAP = Path(__file__).resolve().parents[1] / "data" / "tagmap_dryer1.toml"

#: Modbus limit on registers in one read request (FC 3 / FC 4).
MAX_READ_REGISTERS = 125

TABLES: dict[str, int] = {"holding": 3, "input": 4}  # table -> read function code

_MISSING = object()


@dataclass(frozen=True)
class ModbusSettings:
    """Section ``[modbus]``: where the PLC is and how to poll it."""

    host: str  #: PLC host name or address
    port: int  #: TCP port (502 on a real PLC)
    poll_period_s: float = 10.0  #: scan period [s]
    timeout_s: float = 1.0  #: per request and per connect attempt [s]
    retries: int = 1  #: retries of an unanswered request
    reconnect_delay_s: float = 1.0  #: first reconnect back-off [s], doubled per failure
    reconnect_delay_max_s: float = 30.0  #: cap of the reconnect back-off [s]
    frozen_after_s: float = 300.0  #: a value unchanged bit-for-bit this long is flagged [s]
    max_gap_registers: int = 4  #: unused registers bridged to merge two reads
    max_registers_per_read: int = MAX_READ_REGISTERS  #: cap of one read request


@dataclass(frozen=True)
class TagSpec:
    """Section ``[tags.<signal>]``: one scan signal's place and format in the PLC."""

    signal: str  #: scan signal name (CONTRACT section 1)
    unit_id: int  #: Modbus unit id (pymodbus ``device_id``)
    table: str  #: ``holding`` or ``input``
    address: int  #: first register, 0-based PDU address
    data_type: str  #: key ``type`` in TOML, one of ``registers.DATA_TYPES``
    word_order: str  #: ``big`` or ``little``
    byte_order: str  #: ``big`` or ``little`` (byte swap inside each register)
    scale: float  #: eng = raw * scale + offset
    offset: float  #: [engineering unit]
    unit: str  #: engineering unit, one of ``registers.UNITS``
    valid_min: float  #: lowest valid value [SI]
    valid_max: float  #: highest valid value [SI]
    frozen_after_s: float | None  #: per-tag frozen limit [s]; None = global, 0 = never

    @property
    def count(self) -> int:
        """Number of registers the tag occupies."""
        return DATA_TYPES[self.data_type][1]

    @property
    def function_code(self) -> int:
        """Modbus read function code of the tag's table (3 holding, 4 input)."""
        return TABLES[self.table]

    @property
    def si_unit(self) -> str:
        """SI unit of the signal."""
        return UNITS[self.unit][0]


@dataclass(frozen=True)
class TagMap:
    """A validated tag map: settings plus tags sorted by (unit id, table, address)."""

    modbus: ModbusSettings
    tags: tuple[TagSpec, ...]
    source: str = "<tagmap>"

    @property
    def signals(self) -> tuple[str, ...]:
        """Signal names of the tags, in scan-signal order (CONTRACT section 1)."""
        names = {t.signal for t in self.tags}
        return tuple(s for s in SCAN_SIGNALS if s in names)

    def tag(self, signal: str) -> TagSpec:
        """The tag of ``signal``; KeyError if the map has none."""
        for t in self.tags:
            if t.signal == signal:
                return t
        raise KeyError(signal)

    def with_endpoint(self, host: str, port: int) -> TagMap:
        """A copy that polls ``host:port`` (tests and the command line override the file)."""
        return dataclasses.replace(
            self, modbus=dataclasses.replace(self.modbus, host=host, port=port))

    def with_settings(self, **changes: Any) -> TagMap:
        """A copy with some ``[modbus]`` fields replaced (not re-validated)."""
        return dataclasses.replace(self, modbus=dataclasses.replace(self.modbus, **changes))


@dataclass(frozen=True)
class ReadRequest:
    """One contiguous register read covering one or more tags of one (unit id, table)."""

    unit_id: int
    table: str
    address: int  #: first register read
    count: int  #: registers read, at most 125
    tags: tuple[TagSpec, ...]

    @property
    def function_code(self) -> int:
        """3 for holding registers, 4 for input registers."""
        return TABLES[self.table]

    def slice(self, tag: TagSpec) -> slice:
        """Where ``tag``'s registers sit in this request's response."""
        start = tag.address - self.address
        return slice(start, start + tag.count)


# ---------------------------------------------------------------------------------------------
# loading and validation


class _Checker:
    """Typed lookups in one TOML table that raise ConfigError naming ``source: dotted.key``."""

    def __init__(self, table: Mapping[str, Any], prefix: str, source: str):
        self.table, self.prefix, self.source = table, prefix, source

    def fail(self, key: str, msg: str) -> ConfigError:
        return ConfigError(f"{self.source}: {self.prefix}{key} {msg}")

    def reject_unknown(self, allowed: set[str]) -> None:
        for key in self.table:
            if key not in allowed:
                raise self.fail(key, f"is not a known key (known: {', '.join(sorted(allowed))})")

    def get(self, key: str, default: Any) -> Any:
        if key in self.table:
            return self.table[key]
        if default is _MISSING:
            raise self.fail(key, "is missing")
        return default

    def integer(self, key: str, lo: int, hi: int, default: Any = _MISSING) -> int:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise self.fail(key, f"must be an integer {lo}..{hi}, got {v!r}")
        return v

    def number(self, key: str, default: Any = _MISSING, *, gt: float | None = None,
               ge: float | None = None, nonzero: bool = False) -> float:
        v = self.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(key, f"must be a finite number, got {v!r}")
        if gt is not None and not v > gt:
            raise self.fail(key, f"must be > {gt:g}, got {v!r}")
        if ge is not None and not v >= ge:
            raise self.fail(key, f"must be >= {ge:g}, got {v!r}")
        if nonzero and v == 0:
            raise self.fail(key, "must not be 0")
        return float(v)

    def choice(self, key: str, options: Any, default: Any = _MISSING) -> str:
        v = self.get(key, default)
        if v not in options:
            raise self.fail(key, f"must be one of {', '.join(options)}, got {v!r}")
        return v

    def text(self, key: str, default: Any = _MISSING) -> str:
        v = self.get(key, default)
        if not isinstance(v, str) or not v:
            raise self.fail(key, f"must be a non-empty string, got {v!r}")
        return v


def _settings(table: Any, source: str) -> ModbusSettings:
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}: modbus must be a table, got {table!r}")
    c = _Checker(table, "modbus.", source)
    c.reject_unknown({f.name for f in dataclasses.fields(ModbusSettings)})
    d = ModbusSettings("", 0)  # defaults
    s = ModbusSettings(
        host=c.text("host"),
        port=c.integer("port", 1, 65535),
        poll_period_s=c.number("poll_period_s", d.poll_period_s, gt=0),
        timeout_s=c.number("timeout_s", d.timeout_s, gt=0),
        retries=c.integer("retries", 0, 10, d.retries),
        reconnect_delay_s=c.number("reconnect_delay_s", d.reconnect_delay_s, gt=0),
        reconnect_delay_max_s=c.number("reconnect_delay_max_s", d.reconnect_delay_max_s, gt=0),
        frozen_after_s=c.number("frozen_after_s", d.frozen_after_s, gt=0),
        max_gap_registers=c.integer("max_gap_registers", 0, MAX_READ_REGISTERS,
                                    d.max_gap_registers),
        max_registers_per_read=c.integer("max_registers_per_read", 4, MAX_READ_REGISTERS,
                                         d.max_registers_per_read),
    )
    if s.reconnect_delay_max_s < s.reconnect_delay_s:
        raise c.fail("reconnect_delay_max_s", f"must be >= reconnect_delay_s "
                     f"({s.reconnect_delay_s:g}), got {s.reconnect_delay_max_s:g}")
    return s


_TAG_KEYS = {"unit_id", "table", "address", "type", "word_order", "byte_order", "scale",
             "offset", "unit", "valid_min", "valid_max", "frozen_after_s"}


def _tag(signal: str, table: Any, source: str) -> TagSpec:
    prefix = f"tags.{signal}."
    if signal not in SCAN_SIGNALS:
        raise ConfigError(f"{source}: tags.{signal} is not a scan signal "
                          f"(known: {', '.join(SCAN_SIGNALS)})")
    if not isinstance(table, Mapping):
        raise ConfigError(f"{source}: tags.{signal} must be a table, got {table!r}")
    c = _Checker(table, prefix, source)
    c.reject_unknown(_TAG_KEYS)
    data_type = c.choice("type", tuple(DATA_TYPES))
    address = c.integer("address", 0, 65535)
    n = DATA_TYPES[data_type][1]
    if address + n - 1 > 65535:
        raise c.fail("address", f"leaves no room for {n} registers of {data_type}, "
                     f"got {address}")
    unit = c.choice("unit", tuple(UNITS))
    si_unit = SCAN_SIGNALS[signal]
    if UNITS[unit][0] != si_unit:
        ok = [u for u, (si, _f, _s) in UNITS.items() if si == si_unit]
        raise c.fail("unit", f"must convert to {si_unit} (one of {', '.join(ok)}), "
                     f"got {unit!r}")
    vmin = c.number("valid_min")
    vmax = c.number("valid_max")
    if not vmax > vmin:
        raise c.fail("valid_max", f"must be > valid_min ({vmin:g}), got {vmax:g}")
    frozen = table.get("frozen_after_s")
    return TagSpec(
        signal=signal,
        unit_id=c.integer("unit_id", 0, 255),
        table=c.choice("table", tuple(TABLES)),
        address=address,
        data_type=data_type,
        word_order=c.choice("word_order", ORDERS, "big"),
        byte_order=c.choice("byte_order", ORDERS, "big"),
        scale=c.number("scale", 1.0, nonzero=True),
        offset=c.number("offset", 0.0),
        unit=unit,
        valid_min=vmin,
        valid_max=vmax,
        frozen_after_s=None if frozen is None else c.number("frozen_after_s", ge=0),
    )


def parse_tagmap(data: Mapping[str, Any], source: str = "<tagmap>") -> TagMap:
    """Validate a parsed TOML document and build the :class:`TagMap`.

    ``source`` (usually the file name) starts every error message.
    """
    for key in data:
        if key not in ("modbus", "tags"):
            raise ConfigError(f"{source}: {key} is not a known section (known: modbus, tags)")
    for key in ("modbus", "tags"):
        if key not in data:
            raise ConfigError(f"{source}: {key} is missing")
    settings = _settings(data["modbus"], source)
    tags_table = data["tags"]
    if not isinstance(tags_table, Mapping) or not tags_table:
        raise ConfigError(f"{source}: tags must hold at least one [tags.<signal>] table")
    tags = sorted((_tag(name, t, source) for name, t in tags_table.items()),
                  key=lambda t: (t.unit_id, t.table, t.address))
    for a, b in zip(tags, tags[1:], strict=False):
        if (a.unit_id, a.table) == (b.unit_id, b.table) and b.address < a.address + a.count:
            raise ConfigError(
                f"{source}: tags.{b.signal}.address {b.address} overlaps tags.{a.signal} "
                f"(unit {a.unit_id} {a.table} registers {a.address}..{a.address + a.count - 1})")
    return TagMap(modbus=settings, tags=tuple(tags), source=source)


def load_tagmap(path: str | Path = DEFAULT_TAGMAP) -> TagMap:
    """Read and validate the tag map TOML file at ``path``."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such tag map file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: malformed TOML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.strerror}") from exc
    return parse_tagmap(data, str(path))


# ---------------------------------------------------------------------------------------------
# read planning


def group_reads(tagmap: TagMap) -> list[ReadRequest]:
    """Group the tags into as few contiguous read requests as the limits allow.

    Tags of the same (unit id, table) are merged while the request stays within
    ``modbus.max_registers_per_read`` (at most 125) registers and the unused registers between
    two neighbours number at most ``modbus.max_gap_registers``. Bridged gap registers are read
    and ignored, so the PLC must allow reading them; set ``max_gap_registers = 0`` for a PLC
    that answers an exception for unmapped addresses. Requests come sorted by unit id, table,
    address.
    """
    limit = min(tagmap.modbus.max_registers_per_read, MAX_READ_REGISTERS)
    gap = tagmap.modbus.max_gap_registers
    out: list[ReadRequest] = []
    group: list[TagSpec] = []

    def flush() -> None:
        if group:
            start = group[0].address
            end = max(t.address + t.count for t in group)
            out.append(ReadRequest(group[0].unit_id, group[0].table, start, end - start,
                                   tuple(group)))
            group.clear()

    for tag in sorted(tagmap.tags, key=lambda t: (t.unit_id, t.table, t.address)):
        if group:
            first, last = group[0], group[-1]
            same = (first.unit_id, first.table) == (tag.unit_id, tag.table)
            near = tag.address - (last.address + last.count) <= gap
            fits = tag.address + tag.count - first.address <= limit
            if not (same and near and fits):
                flush()
        group.append(tag)
    flush()
    return out
