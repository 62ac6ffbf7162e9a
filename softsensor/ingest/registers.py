"""Pure register codecs: Modbus register words <-> engineering value <-> SI value.

Sans-I/O: nothing here touches a socket, so every data type, word order and byte order is
tested without a network. The poller decodes with these functions and the simulated PLC
encodes with their inverses, so both sides agree on the layout by construction.

Layout conventions (the four orders of a 32-bit value ``A B C D``, ``A`` the most significant
byte, as PLC manuals name them):

===========  ==========  ==========  =========================================
word_order   byte_order  name        registers for float32 1.0 (0x3F800000)
===========  ==========  ==========  =========================================
big          big         ABCD        ``[0x3F80, 0x0000]`` (Modbus standard)
little       big         CDAB        ``[0x0000, 0x3F80]`` ("word swap")
big          little      BADC        ``[0x803F, 0x0000]`` ("byte swap")
little       little      DCBA        ``[0x0000, 0x803F]``
===========  ==========  ==========  =========================================

A register is a number 0..65535; on the wire its high byte travels first. ``byte_order``
little swaps the two bytes inside every register, ``word_order`` little reverses the order
of the registers. 16-bit types have one register, so only ``byte_order`` matters for them.

Engineering value: ``eng = raw * scale + offset``. SI value: ``si = eng * factor + shift``
with ``(factor, shift)`` from :data:`UNITS`.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Protocol

from softsensor.errors import IngestError

#: Data type name -> (struct format character, number of registers).
DATA_TYPES: dict[str, tuple[str, int]] = {
    "int16": ("h", 1),
    "uint16": ("H", 1),
    "int32": ("i", 2),
    "uint32": ("I", 2),
    "float32": ("f", 2),
    "float64": ("d", 4),
}

#: Inclusive raw range of each integer type.
INT_RANGES: dict[str, tuple[int, int]] = {
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
}

ORDERS: tuple[str, ...] = ("big", "little")

#: Engineering unit -> (SI unit, factor, shift): ``si = eng * factor + shift``.
UNITS: dict[str, tuple[str, float, float]] = {
    "K": ("K", 1.0, 0.0),
    "degC": ("K", 1.0, 273.15),
    "degF": ("K", 5.0 / 9.0, 273.15 - 32.0 * 5.0 / 9.0),
    "kg/s": ("kg/s", 1.0, 0.0),
    "kg/h": ("kg/s", 1.0 / 3600.0, 0.0),
    "t/h": ("kg/s", 1000.0 / 3600.0, 0.0),
    "%": ("%", 1.0, 0.0),
    "kg/kg": ("kg/kg", 1.0, 0.0),
    "g/kg": ("kg/kg", 1.0e-3, 0.0),
}


class TagFormat(Protocol):
    """What the codecs need to know about a tag (satisfied by ``tagmap.TagSpec``)."""

    @property
    def signal(self) -> str: ...
    @property
    def data_type(self) -> str: ...
    @property
    def word_order(self) -> str: ...
    @property
    def byte_order(self) -> str: ...
    @property
    def scale(self) -> float: ...
    @property
    def offset(self) -> float: ...
    @property
    def unit(self) -> str: ...


def register_count(data_type: str) -> int:
    """Number of 16-bit registers a value of ``data_type`` occupies."""
    return DATA_TYPES[data_type][1]


def _swap_bytes(word: int) -> int:
    return ((word & 0xFF) << 8) | (word >> 8)


def _check_format(data_type: str, word_order: str, byte_order: str) -> tuple[str, int]:
    if data_type not in DATA_TYPES:
        raise ValueError(f"unknown data type {data_type!r}")
    if word_order not in ORDERS or byte_order not in ORDERS:
        raise ValueError(f"word/byte order must be 'big' or 'little', got "
                         f"{word_order!r}/{byte_order!r}")
    return DATA_TYPES[data_type]


def decode_raw(registers: Sequence[int], data_type: str, word_order: str = "big",
               byte_order: str = "big") -> int | float:
    """Raw number held in ``registers`` (register words, each 0..65535).

    Raises :class:`~softsensor.errors.IngestError` if the number of registers does not fit the
    type or a word is out of range.
    """
    fmt, n = _check_format(data_type, word_order, byte_order)
    if len(registers) != n:
        raise IngestError(f"{data_type} needs {n} registers, got {len(registers)}")
    words = list(registers)
    for w in words:
        if not isinstance(w, int) or not 0 <= w <= 0xFFFF:
            raise IngestError(f"register word {w!r} is not in 0..65535")
    if byte_order == "little":
        words = [_swap_bytes(w) for w in words]
    if word_order == "little":
        words.reverse()
    return struct.unpack(">" + fmt, struct.pack(f">{n}H", *words))[0]


def encode_raw(value: int | float, data_type: str, word_order: str = "big",
               byte_order: str = "big") -> list[int]:
    """Register words that hold the raw number ``value``; the inverse of :func:`decode_raw`.

    Integer types need an integral ``value`` within the type's range; float types accept any
    float including NaN and infinities. Raises :class:`~softsensor.errors.IngestError` otherwise.
    """
    fmt, n = _check_format(data_type, word_order, byte_order)
    if data_type in INT_RANGES:
        lo, hi = INT_RANGES[data_type]
        if isinstance(value, float):
            if not value.is_integer():
                raise IngestError(f"{data_type} needs an integer, got {value!r}")
            value = int(value)
        if not lo <= value <= hi:
            raise IngestError(f"{value} does not fit {data_type} ({lo}..{hi})")
    else:
        value = float(value)
    words = list(struct.unpack(f">{n}H", struct.pack(">" + fmt, value)))
    if word_order == "little":
        words.reverse()
    if byte_order == "little":
        words = [_swap_bytes(w) for w in words]
    return words


def to_si(eng: float, unit: str) -> float:
    """SI value of the engineering value ``eng`` given in ``unit`` (see :data:`UNITS`)."""
    _si, factor, shift = UNITS[unit]
    return eng * factor + shift


def from_si(si: float, unit: str) -> float:
    """Engineering value in ``unit`` of the SI value ``si``; the inverse of :func:`to_si`."""
    _si, factor, shift = UNITS[unit]
    return (si - shift) / factor


def raw_to_si(raw: int | float, tag: TagFormat) -> float:
    """SI value of a raw register number: ``to_si(raw * scale + offset, unit)``."""
    return to_si(raw * tag.scale + tag.offset, tag.unit)


def decode_tag(registers: Sequence[int], tag: TagFormat) -> float:
    """SI value of ``tag`` held in ``registers`` (NaN and infinities pass through).

    Raises :class:`~softsensor.errors.IngestError` naming the signal on a malformed read.
    """
    try:
        raw = decode_raw(registers, tag.data_type, tag.word_order, tag.byte_order)
    except IngestError as exc:
        raise IngestError(f"{tag.signal}: {exc}") from exc
    return raw_to_si(raw, tag)


def si_to_raw(si: float, tag: TagFormat, *, clip: bool = False) -> int | float:
    """Raw number that represents the SI value ``si`` for ``tag``.

    Integer types are rounded to the nearest count; out-of-range integers raise
    :class:`~softsensor.errors.IngestError`, or saturate at the type's limits with ``clip``.
    NaN or infinity cannot be held by an integer type and always raises.
    """
    raw = (from_si(si, tag.unit) - tag.offset) / tag.scale
    if tag.data_type not in INT_RANGES:
        return raw
    if not math.isfinite(raw):
        raise IngestError(f"{tag.signal}: {si!r} cannot be held by {tag.data_type}")
    lo, hi = INT_RANGES[tag.data_type]
    count = round(raw)
    if clip:
        return min(max(count, lo), hi)
    if not lo <= count <= hi:
        raise IngestError(f"{tag.signal}: {si!r} {UNITS[tag.unit][0]} gives raw {count}, "
                          f"outside {tag.data_type} ({lo}..{hi})")
    return count


def encode_tag(si: float, tag: TagFormat, *, clip: bool = False) -> list[int]:
    """Register words that hold the SI value ``si`` for ``tag``; inverse of :func:`decode_tag`.

    Exact up to the type's resolution: ``|decode_tag(encode_tag(x)) - x| <= resolution(tag, x)``.
    """
    return encode_raw(si_to_raw(si, tag, clip=clip), tag.data_type, tag.word_order,
                      tag.byte_order)


def resolution(tag: TagFormat, si: float = 0.0) -> float:
    """Largest round-trip error [SI unit] of ``tag`` near the SI value ``si``.

    Half a count times the scale for integer types; one unit in the last place for floats.
    """
    _unit, factor, _shift = UNITS[tag.unit]
    if tag.data_type in INT_RANGES:
        return 0.5 * abs(tag.scale * factor) * (1 + 1e-9)
    raw = abs(si_to_raw(si, tag))
    if tag.data_type == "float32":
        ulp = 2.0 ** (math.frexp(max(raw, 1e-30))[1] - 24)
    else:
        ulp = math.ulp(max(raw, 1e-300))
    # a few ulps more for the affine arithmetic in double precision
    return (ulp * abs(tag.scale * factor)) + 4 * math.ulp(max(abs(si), 1.0))
