"""Pure register codecs: fixtures of raw words, round trips, unit conversions (no network)."""

import itertools
import math
import struct
from dataclasses import dataclass

import pytest
from pymodbus.client import AsyncModbusTcpClient

from softsensor.errors import IngestError
from softsensor.ingest.registers import (
    DATA_TYPES,
    INT_RANGES,
    ORDERS,
    decode_raw,
    decode_tag,
    encode_raw,
    encode_tag,
    from_si,
    resolution,
    si_to_raw,
    to_si,
)

ORDER_COMBOS = list(itertools.product(ORDERS, ORDERS))  # (word_order, byte_order)

# Raw-word fixtures worked out by hand from IEEE 754 / two's complement, not from the codec.
# (type, word_order, byte_order, value, registers)
FIXTURES = [
    ("float32", "big", "big", 1.0, [0x3F80, 0x0000]),  # ABCD
    ("float32", "little", "big", 1.0, [0x0000, 0x3F80]),  # CDAB
    ("float32", "big", "little", 1.0, [0x803F, 0x0000]),  # BADC
    ("float32", "little", "little", 1.0, [0x0000, 0x803F]),  # DCBA
    ("float32", "big", "big", -2.5, [0xC020, 0x0000]),
    ("float32", "big", "big", 227.0, [0x4363, 0x0000]),
    ("float64", "big", "big", 1.0, [0x3FF0, 0, 0, 0]),
    ("float64", "little", "big", 1.0, [0, 0, 0, 0x3FF0]),
    ("float64", "big", "little", 1.0, [0xF03F, 0, 0, 0]),
    ("float64", "little", "little", 1.0, [0, 0, 0, 0xF03F]),
    ("float64", "big", "big", 348.0, [0x4075, 0xC000, 0, 0]),
    ("int16", "big", "big", -1, [0xFFFF]),
    ("int16", "big", "big", -32768, [0x8000]),
    ("int16", "big", "little", 0x1234, [0x3412]),
    ("int16", "little", "big", 500, [0x01F4]),  # word order is moot for one register
    ("uint16", "big", "big", 65535, [0xFFFF]),
    ("uint16", "big", "little", 2160, [0x7008]),
    ("int32", "big", "big", -2, [0xFFFF, 0xFFFE]),
    ("int32", "little", "big", -2, [0xFFFE, 0xFFFF]),
    ("int32", "little", "big", 295200, [0x8120, 0x0004]),
    ("uint32", "big", "big", 0x12345678, [0x1234, 0x5678]),
    ("uint32", "little", "big", 0x12345678, [0x5678, 0x1234]),
    ("uint32", "big", "little", 0x12345678, [0x3412, 0x7856]),
    ("uint32", "little", "little", 0x12345678, [0x7856, 0x3412]),
]


@pytest.mark.parametrize(("dtype", "word", "byte", "value", "regs"), FIXTURES)
def test_raw_word_fixtures(dtype, word, byte, value, regs):
    assert decode_raw(regs, dtype, word, byte) == value
    assert encode_raw(value, dtype, word, byte) == regs


def _samples(dtype):
    if dtype in INT_RANGES:
        lo, hi = INT_RANGES[dtype]
        return [lo, hi, 0, 1, lo + 1, hi - 1, (lo + hi) // 3]
    return [0.0, -0.0, 1.0, -2.5, 1.5e-38, 3.0e38, 123.456, math.inf, -math.inf, 1e-45]


@pytest.mark.parametrize(("word", "byte"), ORDER_COMBOS)
@pytest.mark.parametrize("dtype", list(DATA_TYPES))
def test_every_type_and_order_round_trips(dtype, word, byte):
    for v in _samples(dtype):
        regs = encode_raw(v, dtype, word, byte)
        assert len(regs) == DATA_TYPES[dtype][1]
        assert all(0 <= r <= 0xFFFF for r in regs)
        back = decode_raw(regs, dtype, word, byte)
        if dtype == "float32":
            v = struct.unpack(">f", struct.pack(">f", v))[0]  # float32 rounding
        assert back == v and math.copysign(1, back) == math.copysign(1, v)
    # NaN survives bit for bit
    if dtype.startswith("float"):
        regs = encode_raw(math.nan, dtype, word, byte)
        assert math.isnan(decode_raw(regs, dtype, word, byte))


@pytest.mark.parametrize("word", ORDERS)
@pytest.mark.parametrize("dtype", list(DATA_TYPES))
def test_agrees_with_pymodbus_for_standard_byte_order(dtype, word):
    """pymodbus' own converter is the oracle for byte_order big (it has no byte swap)."""
    conv = AsyncModbusTcpClient
    pm_type = getattr(conv.DATATYPE, dtype.upper())
    for v in _samples(dtype)[:7]:
        regs = encode_raw(v, dtype, word, "big")
        assert regs == conv.convert_to_registers(v, pm_type, word_order=word)
        assert decode_raw(regs, dtype, word, "big") == conv.convert_from_registers(
            regs, pm_type, word_order=word)


def test_malformed_reads_raise_ingest_error():
    with pytest.raises(IngestError, match="float32 needs 2 registers, got 1"):
        decode_raw([0x3F80], "float32")
    with pytest.raises(IngestError, match="not in 0..65535"):
        decode_raw([0x10000], "uint16")
    with pytest.raises(IngestError, match="does not fit int16"):
        encode_raw(40000, "int16")
    with pytest.raises(IngestError, match="needs an integer"):
        encode_raw(1.5, "int32")
    with pytest.raises(ValueError, match="unknown data type"):
        decode_raw([0], "int8")


@pytest.mark.parametrize(("eng", "unit", "si"), [
    (0.0, "degC", 273.15), (100.0, "degC", 373.15), (32.0, "degF", 273.15),
    (212.0, "degF", 373.15), (-40.0, "degF", 233.15), (300.0, "K", 300.0),
    (3.6, "t/h", 1.0), (3600.0, "kg/h", 1.0), (2.0, "kg/s", 2.0),
    (10.0, "g/kg", 0.01), (0.01, "kg/kg", 0.01), (45.0, "%", 45.0),
])
def test_unit_conversions(eng, unit, si):
    assert to_si(eng, unit) == pytest.approx(si, rel=1e-12, abs=1e-12)
    assert from_si(si, unit) == pytest.approx(eng, rel=1e-12, abs=1e-12)


@dataclass(frozen=True)
class Tag:
    signal: str
    data_type: str
    word_order: str = "big"
    byte_order: str = "big"
    scale: float = 1.0
    offset: float = 0.0
    unit: str = "K"


@pytest.mark.parametrize(("word", "byte"), ORDER_COMBOS)
@pytest.mark.parametrize(("dtype", "scale", "offset", "unit", "si"), [
    ("int16", 0.1, 0.0, "degC", 268.0),  # -5.15 degC: negative raw
    ("uint16", 0.01, 0.0, "t/h", 6.0),
    ("int32", 0.01, 300.0, "degF", 348.0),  # negative raw through the offset
    ("uint32", 0.001, 0.0, "g/kg", 0.008),
    ("float32", 1.0, 0.0, "degC", 500.0),
    ("float64", 1.0, 0.0, "K", 348.15),
    ("float32", 2.0, -10.0, "kg/h", 82.0),
])
def test_si_round_trip_within_resolution(dtype, scale, offset, unit, si, word, byte):
    tag = Tag("x", dtype, word, byte, scale, offset, unit)
    regs = encode_tag(si, tag)
    assert abs(decode_tag(regs, tag) - si) <= resolution(tag, si)


def test_integer_tags_round_and_clip():
    tag = Tag("m_steam", "int16", scale=0.001, unit="kg/s")
    assert si_to_raw(0.5004, tag) == 500
    assert encode_tag(0.5, tag) == [0x01F4]
    with pytest.raises(IngestError, match="m_steam: 40.0 kg/s gives raw 40000, outside int16"):
        encode_tag(40.0, tag)
    assert encode_tag(40.0, tag, clip=True) == [0x7FFF]
    with pytest.raises(IngestError, match="m_steam: nan cannot be held by int16"):
        encode_tag(math.nan, tag, clip=True)
    with pytest.raises(IngestError, match="^m_steam: int16 needs 1 registers"):
        decode_tag([1, 2], tag)
