"""Fault injection (issue 25, item 8): the Modbus output's function codes, probed with raw
Modbus TCP frames on a real socket (no client library to smooth anything over).

Before: the server answered diagnostics (8), report server id (17) and read device
identification (43), and gave exception 2 (illegal address) to a read of holding registers
(3) and a write of several (16), where docs/interface.md promises exception 1 (illegal
function) to every code but 4.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import threading

import pytest

from softsensor.outputs.modbus_server import N_REGISTERS, EstimateModbusServer
from softsensor.outputs.settings import ModbusOutputSettings
from softsensor.presentation.display import DisplaySettings

#: function code -> request PDU after the code (what a client would send)
REQUESTS: dict[int, bytes] = {
    1: struct.pack(">HH", 0, 8),  # read coils
    2: struct.pack(">HH", 0, 8),  # read discrete inputs
    3: struct.pack(">HH", 0, 2),  # read holding registers
    5: struct.pack(">HH", 0, 0xFF00),  # write single coil
    6: struct.pack(">HH", 0, 5),  # write single register
    8: struct.pack(">HH", 0, 0x1234),  # diagnostics: return query data
    15: struct.pack(">HHB", 0, 1, 1) + b"\x01",  # write multiple coils
    16: struct.pack(">HHB", 0, 1, 2) + b"\x00\x05",  # write multiple registers
    17: b"",  # report server id
    22: struct.pack(">HHH", 0, 0xFFFF, 0),  # mask write register
    23: struct.pack(">HHHHB", 0, 1, 0, 1, 2) + b"\x00\x05",  # read/write multiple
    43: b"\x0e\x01\x00",  # read device identification
}


def _ask(port: int, code: int, pdu: bytes, tid: int) -> bytes:
    frame = struct.pack(">HHHB", tid, 0, len(pdu) + 2, 1) + bytes([code]) + pdu
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(frame)
        head = s.recv(7, socket.MSG_WAITALL)
        assert len(head) == 7, f"function code {code}: no answer"
        rtid, _proto, length, _unit = struct.unpack(">HHHB", head)
        assert rtid == tid
        return s.recv(length - 1, socket.MSG_WAITALL)


def test_every_function_code_but_4_gets_exception_1():
    server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0),
                                  DisplaySettings(moisture_basis="dry"))
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        asyncio.run_coroutine_threadsafe(server.start(), loop).result(10)
        answers = {code: _ask(server.port, code, pdu, tid)
                   for tid, (code, pdu) in enumerate(REQUESTS.items(), 1)}
        ok = _ask(server.port, 4, struct.pack(">HH", 0, N_REGISTERS), 99)
    finally:
        asyncio.run_coroutine_threadsafe(server.stop(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()
    wrong = {code: a.hex() for code, a in answers.items() if a != bytes([code | 0x80, 1])}
    assert not wrong, f"expected exception 1 (code|0x80, 01), got {wrong}"
    assert ok[0] == 4 and ok[1] == 2 * N_REGISTERS  # the estimate block is still served
    assert server.refused >= len(REQUESTS)


@pytest.mark.parametrize("code", [3, 8])
def test_the_rule_is_one_function(code):
    from softsensor.outputs.modbus_protocol import answer_pdu

    out = answer_pdu(bytes([code]) + struct.pack(">HH", 0, 2), [0] * N_REGISTERS)
    assert out == bytes([code | 0x80, 1])
