"""Modbus TCP for the estimate's input registers, sans I/O: bytes in, answers out.

:class:`RegisterProtocol` takes what a connection received, in any cut (half a frame, or many
frames in one TCP segment), and returns the answers to every complete request in order,
keeping the rest for the next bytes; it never touches a socket, so the rules below are tested
without a network (``tests/outputs/test_modbus_protocol.py``) and the server
(:mod:`softsensor.outputs.modbus_server`) only moves bytes. The frame (Modbus Messaging on
TCP/IP Implementation Guide v1.0b, section 3.1.3) is the MBAP header ``transaction (2),
protocol (2) = 0, length (2), unit (1)`` followed by the PDU; ``length`` counts the unit and
the PDU.

What a request gets (Modbus Application Protocol v1.1b3, section 7):

* function code 4 (read input registers) of ``count`` in 1..125 registers within the block:
  the registers;
* function code 4 with a PDU that is not exactly ``04 addr(2) count(2)`` (truncated, or
  trailing bytes) or with ``count`` outside 1..125: exception 3 (illegal data value);
* function code 4 beyond the block: exception 2 (illegal data address);
* every other function code: exception 1 (illegal function);
* unit 255 (0xFF): as the configured unit. The implementation guide above recommends 0xFF
  for a device addressed by its IP address alone, which this server is, and clients that
  follow it send 255 whatever ``unit_id`` says;
* any other unit than the configured one (0 included): exception 11 (gateway target failed to
  respond), as a gateway answers for a device it does not have.

A header that cannot be a Modbus TCP frame (protocol id not 0, a length below 2 or above
254) leaves no way to find the next frame: :class:`FramingError`, and the server closes the
connection.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence

READ_INPUT_REGISTERS = 4
ILLEGAL_FUNCTION = 1
ILLEGAL_DATA_ADDRESS = 2
ILLEGAL_DATA_VALUE = 3
GATEWAY_TARGET_FAILED = 11
#: The unit a client sends to a device addressed by its IP address alone (answered as ours).
ANY_UNIT = 0xFF
#: The most registers one read may ask for (the spec's 0x7D: 250 bytes of data).
MAX_READ = 125
#: MBAP header: transaction, protocol, length (unit included).
_MBAP = struct.Struct(">HHH")
#: The longest ``length`` field: unit + a PDU of at most 253 bytes.
MAX_LENGTH = 254


class FramingError(ValueError):
    """Bytes that are not a Modbus TCP frame; the connection cannot go on."""


def exception_pdu(function_code: int, code: int) -> bytes:
    """The exception response PDU ``function_code | 0x80, code``."""
    return bytes([(function_code | 0x80) & 0xFF, code])


def frame(transaction: int, unit: int, pdu: bytes) -> bytes:
    """The MBAP frame of ``pdu`` for ``transaction`` and ``unit``."""
    return _MBAP.pack(transaction, 0, len(pdu) + 1) + bytes([unit]) + pdu


def answer_pdu(pdu: bytes, registers: Sequence[int]) -> bytes:
    """The response PDU to request ``pdu`` (not empty) against the block ``registers``
    (module docstring)."""
    code = pdu[0]
    if code != READ_INPUT_REGISTERS:
        return exception_pdu(code, ILLEGAL_FUNCTION)
    if len(pdu) != 5:
        return exception_pdu(code, ILLEGAL_DATA_VALUE)
    address, count = struct.unpack(">HH", pdu[1:])
    if not 1 <= count <= MAX_READ:
        return exception_pdu(code, ILLEGAL_DATA_VALUE)
    if address + count > len(registers):
        return exception_pdu(code, ILLEGAL_DATA_ADDRESS)
    words = registers[address:address + count]
    return bytes([code, 2 * count]) + struct.pack(f">{count}H", *words)


class RegisterProtocol:
    """One connection's request parser (module docstring).

    Parameters
    ----------
    unit_id : int
        The unit answered, and :data:`ANY_UNIT` as it; others get exception 11.
    registers : callable
        Returns the register block now (read at each request, so an answer is never older
        than the request).
    """

    def __init__(self, unit_id: int, registers: Callable[[], Sequence[int]]) -> None:
        self.unit_id = unit_id
        self.registers = registers
        self.refused = 0  #: requests answered with an exception
        self._buffer = bytearray()

    @property
    def waiting(self) -> bool:
        """Whether a whole request is buffered, not yet answered (a ``feed`` with
        ``max_requests`` left it)."""
        if len(self._buffer) < _MBAP.size:
            return False
        _transaction, _protocol, length = _MBAP.unpack_from(self._buffer)
        return len(self._buffer) >= _MBAP.size + length

    def feed(self, data: bytes, max_requests: int | None = None) -> list[bytes]:
        """The answer frames to the requests completed by ``data``, in order: every one, or
        the first ``max_requests`` (the rest stay buffered for the next call, see
        :attr:`waiting`); raises :class:`FramingError` on a header that cannot be framed."""
        self._buffer += data
        out: list[bytes] = []
        while len(self._buffer) >= _MBAP.size and (max_requests is None
                                                   or len(out) < max_requests):
            transaction, protocol, length = _MBAP.unpack_from(self._buffer)
            if protocol != 0 or not 2 <= length <= MAX_LENGTH:
                self._buffer.clear()
                raise FramingError(f"not a Modbus TCP header (protocol {protocol}, length "
                                   f"{length})")
            end = _MBAP.size + length
            if len(self._buffer) < end:
                break
            unit, pdu = self._buffer[_MBAP.size], bytes(self._buffer[_MBAP.size + 1:end])
            del self._buffer[:end]
            if unit not in (self.unit_id, ANY_UNIT):
                answer = exception_pdu(pdu[0], GATEWAY_TARGET_FAILED)
            else:
                answer = answer_pdu(pdu, self.registers())
            if answer[0] & 0x80:
                self.refused += 1
            out.append(frame(transaction, unit, answer))
        return out


__all__ = ["ANY_UNIT", "GATEWAY_TARGET_FAILED", "ILLEGAL_DATA_ADDRESS", "ILLEGAL_DATA_VALUE",
           "ILLEGAL_FUNCTION", "MAX_READ", "READ_INPUT_REGISTERS", "FramingError",
           "RegisterProtocol", "answer_pdu", "exception_pdu", "frame"]
