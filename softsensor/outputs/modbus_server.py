"""The latest estimate as Modbus input registers, for a DCS to poll (``[outputs.modbus]``).

A pymodbus 3.16 TCP server on its own port (loopback unless configured) holds one block of
input registers (function code 4), laid out in docs/interface.md section 7 and in
:data:`REGISTERS`: the outlet and inlet moisture with their standard deviations [kg/kg dry
basis] and in % on the display basis, the window end [s since the epoch, UTC], the health
code, a counter of estimates and whether a lab result corrected this window. Floats are
IEEE-754 float32, high word first (ABCD), integers unsigned and big-endian; an estimate that
is missing is NaN with the health code saying why.

The server serves the estimator's outputs and nothing else: every other function code,
writes, diagnostics (8), server id (17) and device identification (43) included, is answered
with exception 1 (illegal function). pymodbus answers some of them itself (8, 17, 43) or
validates the address first (exception 2 to a read of holding registers), so the rule is
applied where every response leaves: a response to anything but function code 4 is replaced
by exception 1 (:func:`only_input_registers`). The softsensor's Modbus client to the PLC is a
different program path and never writes either.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import struct
from collections.abc import Mapping
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.settings import ModbusOutputSettings
from softsensor.presentation.display import DisplaySettings, moisture_pct

log = logging.getLogger(__name__)

#: name -> (first register, type); the block is :data:`N_REGISTERS` long from address 0.
REGISTERS: dict[str, tuple[int, str]] = {
    "moisture_out": (0, "float32"),
    "moisture_out_std": (2, "float32"),
    "moisture_in": (4, "float32"),
    "moisture_in_std": (6, "float32"),
    "moisture_out_pct": (8, "float32"),
    "moisture_in_pct": (10, "float32"),
    "window_end_s": (12, "uint32"),
    "health": (14, "uint16"),
    "counter": (15, "uint16"),
    "lab_updated": (16, "uint16"),
}
N_REGISTERS = 17
#: Health codes of register 14.
HEALTH_CODES: dict[str, int] = {"ok": 0, "degraded": 1, "stale": 2}
NO_ESTIMATE = 3
READ_INPUT_REGISTERS = 4


def _words(value: float | int, kind: str) -> list[int]:
    if kind == "float32":
        raw = struct.pack(">f", math.nan if value is None else float(value))
    elif kind == "uint32":
        raw = struct.pack(">I", int(value) & 0xFFFFFFFF)
    else:
        raw = struct.pack(">H", int(value) & 0xFFFF)
    return list(struct.unpack(f">{len(raw) // 2}H", raw))


def estimate_registers(body: Mapping[str, Any], time_ns: int, counter: int,
                       display: DisplaySettings) -> list[int]:
    """The whole register block for one estimate body (docs/interface.md section 5)."""
    basis = display.moisture_basis

    def num(key: str) -> float:
        v = body.get(key)
        return math.nan if v is None or not math.isfinite(float(v)) else float(v)

    values: dict[str, float | int] = {k: num(k) for k in
                                      ("moisture_out", "moisture_out_std", "moisture_in",
                                       "moisture_in_std")}
    values["moisture_out_pct"] = float(moisture_pct(values["moisture_out"], basis))
    values["moisture_in_pct"] = float(moisture_pct(values["moisture_in"], basis))
    values["window_end_s"] = time_ns // 10**9
    values["health"] = HEALTH_CODES.get(str(body.get("status")), NO_ESTIMATE)
    values["counter"] = counter
    values["lab_updated"] = 1 if body.get("lab_updated") else 0
    words = [0] * N_REGISTERS
    for name, (addr, kind) in REGISTERS.items():
        w = _words(values[name], kind)
        words[addr:addr + len(w)] = w
    return words


def only_input_registers(pdu: ModbusPDU) -> ModbusPDU:
    """The response ``pdu`` if it answers function code 4, else exception 1 in its place
    (same transaction and unit)."""
    code = pdu.function_code & 0x7F
    if code == READ_INPUT_REGISTERS:
        return pdu
    return ExceptionResponse(code, ExcCodes.ILLEGAL_FUNCTION, device_id=pdu.dev_id,
                             transaction=pdu.transaction_id)


def _bind_problem(host: str, port: int, exc: BaseException) -> str:
    """Why ``host:port`` cannot be listened on, as the system says it ("Address already in
    use"): tried with a plain socket, since pymodbus hides the reason."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    try:
        for family, kind, proto, _name, address in socket.getaddrinfo(
                host, port, type=socket.SOCK_STREAM):
            with socket.socket(family, kind, proto) as probe:
                probe.bind(address)
    except OSError as err:
        return err.strerror or str(err)
    return str(exc)


class EstimateModbusServer:
    """The register server (module docstring), an
    :class:`~softsensor.outputs.operator_output.OperatorOutput`: :meth:`on_estimate` may be
    called from any thread once :meth:`start` has run in the daemon's event loop."""

    name = "modbus"

    def __init__(self, settings: ModbusOutputSettings, display: DisplaySettings) -> None:
        self.settings = settings
        self.display = display
        self.counter = 0
        self.refused = 0  #: requests answered with an exception (writes, other tables)
        self._server: ModbusTcpServer | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self.port = settings.port

    async def _action(self, function_code: int, _start: int, _address: int, _count: int,
                      _registers: list[int], _set_values: object) -> ExcCodes | None:
        if function_code != READ_INPUT_REGISTERS:
            return ExcCodes.ILLEGAL_FUNCTION  # (counted in _trace, where it leaves)
        return None

    def _trace(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        """pymodbus's hook on every PDU in and out: responses pass :func:`only_input_registers`."""
        if not sending:
            return pdu
        out = only_input_registers(pdu)
        if out is not pdu:
            self.refused += 1
        return out

    def _device(self) -> SimDevice:
        empty = [SimData(address=0, values=0, datatype=DataType.BITS)]
        holding = [SimData(address=0, values=0, datatype=DataType.REGISTERS)]
        block = [SimData(address=0, count=N_REGISTERS, values=0, datatype=DataType.REGISTERS)]
        return SimDevice(id=self.settings.unit_id, simdata=(empty, list(empty), holding, block),
                         action=self._action)

    async def start(self) -> str:
        """Bind and serve; NaN estimates and health 3 until the first estimate. What it
        serves: ``modbus://host:port``."""
        s = self.settings
        server = ModbusTcpServer([self._device()], address=(s.host, s.port),
                                 trace_pdu=self._trace)
        try:
            await server.serve_forever(background=True)
        except (OSError, RuntimeError) as exc:
            # pymodbus says only "Could not start listen" (a RuntimeError) for a busy port
            with contextlib.suppress(Exception):
                await server.shutdown()
            raise ConfigError(f"outputs.modbus: cannot listen on {s.host}:{s.port}: "
                              f"{_bind_problem(s.host, s.port, exc)}") from exc
        self._server, self._loop = server, asyncio.get_running_loop()
        sockets = getattr(server.transport, "sockets", None)
        if sockets:
            self.port = sockets[0].getsockname()[1]
        await self._store(estimate_registers({}, 0, 0, self.display))
        log.info("estimate registers served on %s:%d", s.host, self.port)
        return f"modbus://{s.host}:{self.port}"

    async def _store(self, words: list[int]) -> None:
        if self._server is not None:
            await self._server.async_setValues(self.settings.unit_id, READ_INPUT_REGISTERS, 0,
                                               words)

    def on_estimate(self, estimate: Estimate) -> None:
        """Serve a new estimate (thread-safe: handed to the server's event loop)."""
        if self._loop is None:
            return
        self.counter += 1
        words = estimate_registers(estimate.to_body(), estimate.time_ns, self.counter,
                                   self.display)
        asyncio.run_coroutine_threadsafe(self._store(words), self._loop)

    def on_health(self, health: Health) -> None:
        """A health change between estimates (e.g. ``stale`` when scans stop): register 14."""
        if self._loop is None:
            return
        code = HEALTH_CODES.get(health.status, NO_ESTIMATE)

        async def _set() -> None:
            if self._server is not None:
                await self._server.async_setValues(self.settings.unit_id, READ_INPUT_REGISTERS,
                                                   REGISTERS["health"][0], [code])

        asyncio.run_coroutine_threadsafe(_set(), self._loop)

    def on_lab(self, lab: LabResult) -> None:
        """Lab results are not served as registers."""

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            with contextlib.suppress(Exception):
                await server.shutdown()


__all__ = ["HEALTH_CODES", "N_REGISTERS", "NO_ESTIMATE", "REGISTERS", "EstimateModbusServer",
           "estimate_registers"]
