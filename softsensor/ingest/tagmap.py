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

Loaded once into frozen dataclasses by :func:`softsensor.configfile.build_section` (the
mechanism every config file uses); unknown keys, unknown signals and bad values raise
:class:`~softsensor.errors.ConfigError` with one line naming the file and the dotted key.
A tag map may hold a subset of the scan signals (the scan body then carries that subset).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from softsensor.configfile import build_section, choice, num, read_toml
from softsensor.errors import ConfigError
from softsensor.ingest.registers import DATA_TYPES, ORDERS, UNITS
from softsensor.signals import SCAN_SIGNALS

#: The reference tag map, shipped in the package (the repository's config/tagmap_dryer1.toml
#: links to it).
DEFAULT_TAGMAP = Path(__file__).resolve().parents[1] / "data" / "tagmap_dryer1.toml"

#: Modbus limit on registers in one read request (FC 3 / FC 4).
MAX_READ_REGISTERS = 125

TABLES: dict[str, int] = {"holding": 3, "input": 4}  # table -> read function code

@dataclass(frozen=True)
class ModbusSettings:
    """Section ``[modbus]``: where the PLC is and how to poll it."""

    host: str  #: PLC host name or address
    port: int = num(ge=1, le=65535)  #: TCP port (502 on a real PLC)
    poll_period_s: float = num(10.0, gt=0, le=3600)  #: scan period [s]
    timeout_s: float = num(1.0, gt=0, le=60)  #: per request and per connect attempt [s]
    retries: int = num(1, ge=0, le=10)  #: retries of an unanswered request
    #: first reconnect back-off [s], doubled per failure
    reconnect_delay_s: float = num(1.0, gt=0, le=3600)
    reconnect_delay_max_s: float = num(30.0, gt=0, le=3600)  #: cap of the reconnect back-off [s]
    #: a value unchanged bit-for-bit this long is flagged [s]
    frozen_after_s: float = num(300.0, gt=0, le=7 * 86_400)
    #: unused registers bridged to merge two reads
    max_gap_registers: int = num(4, ge=0, le=MAX_READ_REGISTERS)
    #: cap of one read request
    max_registers_per_read: int = num(MAX_READ_REGISTERS, ge=4, le=MAX_READ_REGISTERS)

    def check(self) -> str | None:
        """Cross-field rule (called by ``build_section``); the message names the key."""
        if self.reconnect_delay_max_s < self.reconnect_delay_s:
            return (f"reconnect_delay_max_s must be >= reconnect_delay_s "
                    f"({self.reconnect_delay_s:g}), got {self.reconnect_delay_max_s:g}")
        return None


@dataclass(frozen=True)
class TagSpec:
    """Section ``[tags.<signal>]``: one scan signal's place and format in the PLC."""

    signal: str  #: scan signal name (CONTRACT section 1), the name of the table
    unit_id: int = num(ge=0, le=255)  #: Modbus unit id (pymodbus ``device_id``)
    table: str = choice(TABLES)  #: ``holding`` or ``input``
    address: int = num(ge=0, le=65535)  #: first register, 0-based PDU address
    #: key ``type`` in TOML, one of ``registers.DATA_TYPES``
    data_type: str = choice(DATA_TYPES, toml_key="type")
    unit: str = choice(UNITS)  #: engineering unit, one of ``registers.UNITS``
    valid_min: float = num()  #: lowest valid value [SI]
    valid_max: float = num()  #: highest valid value [SI]
    word_order: str = choice(ORDERS, "big")  #: ``big`` or ``little``
    #: ``big`` or ``little`` (byte swap inside each register)
    byte_order: str = choice(ORDERS, "big")
    scale: float = num(1.0)  #: eng = raw * scale + offset
    offset: float = num(0.0)  #: [engineering unit]
    #: per-tag frozen limit [s]; None = global, 0 = never
    frozen_after_s: float | None = num(None, ge=0)

    def check(self) -> str | None:
        """Cross-field rules (called by ``build_section``); the message names the key."""
        if self.address + self.count - 1 > 65535:
            return (f"address leaves no room for {self.count} registers of {self.data_type}, "
                    f"got {self.address}")
        si_unit = SCAN_SIGNALS[self.signal]
        if self.si_unit != si_unit:
            ok = [u for u, (si, _f, _s) in UNITS.items() if si == si_unit]
            return (f"unit must convert to {si_unit} (one of {', '.join(ok)}), "
                    f"got {self.unit!r}")
        if not self.valid_max > self.valid_min:
            return (f"valid_max must be > valid_min ({self.valid_min:g}), "
                    f"got {self.valid_max:g}")
        if self.scale == 0:
            return "scale must not be 0"
        return None

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
class ClockSpec:
    """Section ``[clock]`` (optional): where the PLC serves its clock, two registers holding
    uint32 seconds since the Unix epoch (UTC), high word first. The virtual PLC serves its
    plant's clock there; ``softsensor run --clock-start plc`` starts the daemon's clock from
    it, so an accelerated demo has one clock, not two."""

    unit_id: int = num(ge=0, le=255)  #: Modbus unit id
    table: str = choice(TABLES)  #: ``holding`` or ``input``
    address: int = num(ge=0, le=65534)  #: first of the two registers, 0-based PDU address
    count: ClassVar[int] = 2


@dataclass(frozen=True)
class TagMap:
    """A validated tag map: settings plus tags sorted by (unit id, table, address)."""

    modbus: ModbusSettings
    tags: tuple[TagSpec, ...]
    source: str = "<tagmap>"
    clock: ClockSpec | None = None  #: where the PLC serves its clock, if it does

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
# loading and validation (softsensor.configfile: the one config schema mechanism)


def _tag(signal: str, table: Any, source: str) -> TagSpec:
    if signal not in SCAN_SIGNALS:
        raise ConfigError(f"{source}: tags.{signal} is not a scan signal "
                          f"(known: {', '.join(SCAN_SIGNALS)})")
    return build_section(TagSpec, table, f"tags.{signal}", source, given={"signal": signal})


def parse_tagmap(data: Mapping[str, Any], source: str = "<tagmap>") -> TagMap:
    """Validate a parsed TOML document and build the :class:`TagMap`.

    ``source`` (usually the file name) starts every error message.
    """
    for key in data:
        if key not in ("modbus", "tags", "clock"):
            raise ConfigError(f"{source}: {key} is not a known section (known: modbus, tags, "
                              f"clock)")
    for key in ("modbus", "tags"):
        if key not in data:
            raise ConfigError(f"{source}: {key} is missing")
    settings = build_section(ModbusSettings, data["modbus"], "modbus", source)
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
    clock = None
    if "clock" in data:
        clock = build_section(ClockSpec, data["clock"], "clock", source)
        for t in tags:
            if (t.unit_id, t.table) == (clock.unit_id, clock.table) \
                    and clock.address < t.address + t.count and t.address < clock.address + 2:
                raise ConfigError(f"{source}: clock.address {clock.address} overlaps "
                                  f"tags.{t.signal}")
    return TagMap(modbus=settings, tags=tuple(tags), source=source, clock=clock)


def load_tagmap(path: str | Path = DEFAULT_TAGMAP) -> TagMap:
    """Read and validate the tag map TOML file at ``path``."""
    return parse_tagmap(read_toml(path), str(path))


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
