"""The Modbus TCP rules of the register server, without a network
(``softsensor/outputs/modbus_protocol.py``, issue 40): exception codes, pipelined and split
requests, units, and headers that cannot be framed. The same rules on a real socket:
``tests/faults/test_modbus_output_limits.py``."""

from __future__ import annotations

import struct

import pytest

from softsensor.outputs.modbus_protocol import FramingError, RegisterProtocol, frame

BLOCK = list(range(100, 117))  # 17 registers, each its own value


def _request(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return frame(tid, unit, pdu)


def _read(tid: int, address: int, count: int, unit: int = 1) -> bytes:
    return _request(tid, struct.pack(">BHH", 4, address, count), unit)


def _answer(data: bytes) -> tuple[int, int, bytes]:
    tid, proto, length, unit = struct.unpack(">HHHB", data[:7])
    assert proto == 0 and length == len(data) - 6
    return tid, unit, data[7:]


@pytest.mark.parametrize(("pdu", "why"), [
    (struct.pack(">BHH", 4, 0, 0), "count 0"),
    (struct.pack(">BHH", 4, 0, 126), "count above 125"),
    (struct.pack(">BHH", 4, 0, 2000), "over-long read"),
    (bytes([4, 0, 0, 0]), "truncated PDU"),
    (bytes([4]), "function code alone"),
    (struct.pack(">BHH", 4, 0, 2) + b"\x00", "trailing byte"),
])
def test_a_malformed_read_gets_exception_3(pdu, why):
    p = RegisterProtocol(1, lambda: BLOCK)
    [out] = p.feed(_request(9, pdu))
    assert _answer(out) == (9, 1, b"\x84\x03"), why
    assert p.refused == 1


def test_a_read_beyond_the_block_gets_exception_2_and_a_good_one_its_registers():
    p = RegisterProtocol(1, lambda: BLOCK)
    beyond, whole, last = p.feed(_read(1, 16, 2) + _read(2, 0, 17) + _read(3, 16, 1))
    assert _answer(beyond)[2] == b"\x84\x02"
    assert _answer(whole)[2] == bytes([4, 34]) + struct.pack(">17H", *BLOCK)
    assert _answer(last)[2] == bytes([4, 2, 0, 116])


@pytest.mark.parametrize("unit", [0, 2, 254])
def test_another_unit_gets_exception_11(unit):
    [out] = RegisterProtocol(1, lambda: BLOCK).feed(_read(5, 0, 2, unit=unit))
    assert _answer(out) == (5, unit, b"\x84\x0b")


@pytest.mark.parametrize("unit_id", [1, 17])
def test_unit_255_is_answered_as_the_configured_unit(unit_id):
    """0xFF is what the Modbus TCP guide tells a client to send to a device addressed by
    its IP address alone; it got exception 11."""
    p = RegisterProtocol(unit_id, lambda: BLOCK)
    ours, any_unit = p.feed(_read(5, 0, 2, unit=unit_id) + _read(6, 0, 2, unit=255))
    assert _answer(any_unit) == (6, 255, _answer(ours)[2]) and p.refused == 0
    assert _answer(ours)[2] == bytes([4, 4, 0, 100, 0, 101])


def test_pipelined_requests_are_answered_in_order_and_a_split_one_when_complete():
    p = RegisterProtocol(1, lambda: BLOCK)
    stream = b"".join(_read(tid, tid % 17, 1) for tid in range(1, 1001))
    answers = p.feed(stream[:-3])  # the last request cut in two
    assert [_answer(a)[0] for a in answers] == list(range(1, 1000))
    assert [_answer(a)[2][-1] for a in answers] == [100 + tid % 17 for tid in range(1, 1000)]
    [last] = p.feed(stream[-3:])
    assert _answer(last)[0] == 1000
    assert p.feed(b"") == []


def test_a_budget_answers_that_many_and_keeps_the_rest_waiting_in_order():
    p = RegisterProtocol(1, lambda: BLOCK)
    stream = b"".join(_read(tid, 0, 1) for tid in range(1, 101))
    got = p.feed(stream[:-3], max_requests=32)
    assert [_answer(a)[0] for a in got] == list(range(1, 33)) and p.waiting
    got += p.feed(b"", max_requests=60)
    got += p.feed(b"", max_requests=32)  # 7 whole ones left, the last still cut
    assert len(got) == 99 and not p.waiting
    got += p.feed(stream[-3:], max_requests=0)
    assert len(got) == 99 and p.waiting
    got += p.feed(b"", max_requests=5)
    assert [_answer(a)[0] for a in got] == list(range(1, 101)) and not p.waiting


@pytest.mark.parametrize("head", [struct.pack(">HHHB", 1, 7, 6, 1),  # protocol id 7
                                  struct.pack(">HHHB", 1, 0, 1, 1),  # no function code
                                  struct.pack(">HHHB", 1, 0, 300, 1)])  # beyond 254
def test_a_header_that_cannot_be_framed_ends_the_connection(head):
    with pytest.raises(FramingError):
        RegisterProtocol(1, lambda: BLOCK).feed(head + b"\x04\x00\x00\x00\x01")
