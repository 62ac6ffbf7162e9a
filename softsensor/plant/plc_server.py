"""A simulated PLC: a pymodbus 3.16 Modbus TCP server laid out by the tag map.

The server holds, for every unit id of the tag map, one holding-register block and one
input-register block spanning the tags' addresses (unused registers in between read as 0, so
the poller may bridge gaps). Every ``period_s`` it asks a value source for SI values
(``next_values() -> {signal: value}``), encodes them with :mod:`softsensor.ingest.registers`
and stores them with ``await server.async_setValues(...)``. The virtual plant plugs in as that
value source.

Like a real PLC's process image it is read-only from the network: every write request
(function codes 5, 6, 15, 16, 21, 22, 23) is answered with exception 1 (illegal function) and
counted in :attr:`PlcServer.write_requests`, observed through pymodbus' ``trace_pdu`` hook,
which sees every request PDU the server decodes. Tests use it to prove the poller never writes.

With a ``clock`` (the plant's time of the values served) and a ``[clock]`` table in the tag
map, the two registers there hold that time as uint32 seconds since the epoch, high word
first, updated with the values: a daemon started with ``--clock-start plc`` starts its clock
there, so the lab files the virtual plant drops (stamped on the plant's clock) and the scans the
daemon stamps agree (two clocks made every lab of a demo arrive "before it was sampled").

Fault injection for tests: :meth:`PlcServer.set_raw` stores raw words (NaN, frozen values),
:meth:`PlcServer.inject_fault` makes reads that touch a signal's registers answer exception 4
(device failure). ``stop()`` closes the listener and all connections; ``start()`` again binds
the same port.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import os
import socket
from collections.abc import Callable, Mapping, Sequence

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ModbusPDU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from softsensor.errors import ConfigError, IngestError
from softsensor.ingest.registers import encode_tag
from softsensor.ingest.tagmap import TABLES, TagMap, TagSpec

log = logging.getLogger(__name__)

#: Modbus function codes that write: coils (5, 15), registers (6, 16), file record (21),
#: mask write (22), read/write multiple (23).
WRITE_FUNCTION_CODES: frozenset[int] = frozenset({5, 6, 15, 16, 21, 22, 23})

#: Function codes of register reads, by table.
_FC_TABLE = {3: "holding", 4: "input"}

ValueSource = Callable[[], Mapping[str, float]]


class PlcServer:
    """Simulated PLC serving the tag map's registers on ``host:port``.

    Parameters
    ----------
    tagmap
        Layout of the registers; its ``[modbus]`` host and port are not used.
    next_values
        Value source, called once per period: SI values per signal [K, kg/s, kg/kg, %].
        Signals it omits keep their previous registers; unknown names are ignored.
    host, port
        Address to bind; ``port=0`` lets the OS choose (see ``port`` after ``start``).
    period_s
        Update period [s]; default the tag map's poll period.
    clock
        The plant's time of the values served [ns since the epoch], served at the tag map's
        ``[clock]`` registers (module docstring); None: no clock.
    """

    def __init__(self, tagmap: TagMap, next_values: ValueSource, *, host: str = "127.0.0.1",
                 port: int = 0, period_s: float | None = None,
                 clock: Callable[[], int] | None = None):
        self.tagmap = tagmap
        self.next_values = next_values
        self.clock = clock
        self.host = host
        self.port = port
        self.period_s = tagmap.modbus.poll_period_s if period_s is None else period_s
        self.write_requests = 0  #: write requests received (FC 5, 6, 15, 16, 21, 22, 23)
        self.requests = 0  #: all requests received
        self.updates = 0  #: value updates done
        self.last_values: dict[str, float] = {}  #: SI values of the last update
        self._tags = {t.signal: t for t in tagmap.tags}
        self._faults: set[str] = set()
        self._server: ModbusTcpServer | None = None
        self._task: asyncio.Task[None] | None = None

    # -- layout ---------------------------------------------------------------------------

    def _devices(self) -> list[SimDevice]:
        devices = []
        spans = [(t.unit_id, t.table, t.address, t.count) for t in self.tagmap.tags]
        c = self.tagmap.clock
        if c is not None and self.clock is not None:
            spans.append((c.unit_id, c.table, c.address, c.count))
        for unit in sorted({s[0] for s in spans}):
            blocks: dict[str, list[SimData]] = {}
            for table in TABLES:
                tags = [s for s in spans if s[:2] == (unit, table)]
                if tags:
                    start = min(s[2] for s in tags)
                    end = max(s[2] + s[3] for s in tags)
                    blocks[table] = [SimData(address=start, count=end - start, values=0,
                                             datatype=DataType.REGISTERS)]
                else:  # pymodbus needs a non-empty block; one register nobody reads
                    blocks[table] = [SimData(address=0, values=0, datatype=DataType.REGISTERS)]
            bits = [SimData(address=0, values=0, datatype=DataType.BITS)]
            devices.append(SimDevice(
                id=unit,
                simdata=(bits, list(bits), blocks["holding"], blocks["input"]),
                action=functools.partial(self._action, unit),
            ))
        if all(d.id != 0 for d in devices):  # id 0: every unit id not configured above
            devices.append(SimDevice(
                id=0, simdata=[SimData(address=0, values=0, datatype=DataType.REGISTERS)],
                action=_no_such_unit))
        return devices

    async def _action(self, unit: int, function_code: int, _start: int, address: int,
                      count: int, _registers: list[int], set_values: object) -> ExcCodes | None:
        """Called by pymodbus for every access to a device's registers."""
        if function_code in WRITE_FUNCTION_CODES:
            return ExcCodes.ILLEGAL_FUNCTION  # read-only process image
        table = _FC_TABLE.get(function_code)
        if set_values is None and table and self._faults:
            for sig in self._faults:
                t = self._tags[sig]
                if ((t.unit_id, t.table) == (unit, table)
                        and address < t.address + t.count and t.address < address + count):
                    return ExcCodes.DEVICE_FAILURE
        return None

    def _trace_pdu(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        """pymodbus hook: sees every PDU the server receives (sending False) or sends."""
        if not sending:
            self.requests += 1
            if pdu.function_code in WRITE_FUNCTION_CODES:
                self.write_requests += 1
                log.warning("PLC simulator: write request FC %d refused", pdu.function_code)
        return pdu

    # -- lifecycle ------------------------------------------------------------------------

    @property
    def running(self) -> bool:
        """True while the server listens."""
        return self._server is not None

    async def start(self) -> None:
        """Bind, store the first values and start the periodic update; no-op if running."""
        if self._server is not None:
            return
        server = ModbusTcpServer(self._devices(), address=(self.host, self.port),
                                 trace_pdu=self._trace_pdu)
        self._server = server
        try:
            await self._update(self.next_values())  # before serving: no zero registers
            await server.serve_forever(background=True)
        except BaseException as exc:
            self._server = None
            with contextlib.suppress(Exception):
                await server.shutdown()
            if isinstance(exc, (RuntimeError, OSError)):  # pymodbus: "Could not start listen"
                raise ConfigError(f"PLC simulator cannot listen on {self.host}:{self.port} "
                                  f"(in use, or not an address of this machine)") from exc
            raise
        sockets = getattr(server.transport, "sockets", None)
        if sockets:
            self.port = sockets[0].getsockname()[1]
        self._task = asyncio.create_task(self._run(), name="plc-simulator-update")
        log.info("PLC simulator listening on %s:%d", self.host, self.port)

    async def stop(self) -> None:
        """Stop updating, close the listener and every client connection."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()
            await asyncio.sleep(0)  # let asyncio close the transports

    async def __aenter__(self) -> PlcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        next_t = loop.time() + self.period_s
        while True:
            await asyncio.sleep(max(0.0, next_t - loop.time()))
            next_t += self.period_s
            try:
                await self.update_once()
            except Exception:  # a broken value source must not kill the PLC
                log.exception("PLC simulator: value source failed")

    # -- values ---------------------------------------------------------------------------

    async def update_once(self) -> None:
        """Pull one set of values from the value source and store them."""
        await self._update(self.next_values())

    async def set_values(self, values: Mapping[str, float]) -> None:
        """Store SI values now (outside the periodic update)."""
        await self._update(values)

    async def _update(self, values: Mapping[str, float]) -> None:
        for sig, si in values.items():
            tag = self._tags.get(sig)
            if tag is None:
                continue
            try:
                words = encode_tag(si, tag, clip=True)
            except IngestError as exc:  # e.g. NaN into an integer register: keep old value
                log.warning("PLC simulator: %s", exc)
                continue
            await self._store(tag, words)
            self.last_values[sig] = float(si)
        c = self.tagmap.clock
        if c is not None and self.clock is not None and self._server is not None:
            s = max(0, min(int(self.clock()) // 10**9, 2**32 - 1))
            await self._server.async_setValues(c.unit_id, TABLES[c.table], c.address,
                                               [s >> 16, s & 0xFFFF])
        self.updates += 1

    async def set_raw(self, signal: str, registers: Sequence[int]) -> None:
        """Store raw register words for ``signal`` (for fault injection in tests)."""
        tag = self._tags[signal]
        if len(registers) != tag.count:
            raise ValueError(f"{signal} needs {tag.count} registers, got {len(registers)}")
        await self._store(tag, list(registers))

    async def _store(self, tag: TagSpec, words: list[int]) -> None:
        if self._server is None:
            raise RuntimeError("PLC simulator is not running")
        await self._server.async_setValues(tag.unit_id, tag.function_code, tag.address, words)

    def inject_fault(self, signal: str, active: bool = True) -> None:
        """Make reads touching ``signal``'s registers answer exception 4 (device failure)."""
        if signal not in self._tags:
            raise KeyError(signal)
        if active:
            self._faults.add(signal)
        else:
            self._faults.discard(signal)


def check_port(host: str, port: int) -> None:
    """Refuse, before anything slow starts, a port this machine cannot listen on (in use,
    or ``host`` not one of its addresses): the virtual plant simulates a day before it
    serves, and "address already in use" after that half minute helps nobody."""
    if port == 0:
        return
    try:
        with socket.create_server((host, port), reuse_port=False) as _:
            pass
    except OSError as exc:
        raise ConfigError(f"plant-server cannot listen on {host}:{port}: "
                          f"{os.strerror(exc.errno) if exc.errno else exc} (another --port?)"
                          ) from exc


async def _no_such_unit(*_args: object) -> ExcCodes:
    """Answer of an unconfigured unit id, as a Modbus gateway would (exception 11)."""
    return ExcCodes.GATEWAY_NO_RESPONSE


def constant_values(values: Mapping[str, float]) -> ValueSource:
    """A value source that always returns ``values`` (SI) - for tests and demos."""
    frozen = dict(values)
    return lambda: frozen


#: A plausible operating point of dryer1 in SI units (CONTRACT section 6).
NOMINAL_VALUES: dict[str, float] = {
    "T_air_in": 500.0,
    "m_air": 82.0,
    "m_fiber": 6.0,
    "T_fiber_in": 370.0,
    "m_steam": 0.5,
    "T_amb": 283.15,
    "H_amb": 0.008,
    "flap_cmd": 45.0,
    "T_sp": 348.15,
    "T_dryer_out": 348.0,
    "T_cyclone_out": 338.0,
}
