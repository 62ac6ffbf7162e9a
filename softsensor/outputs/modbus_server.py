"""The latest estimate as Modbus input registers, for a DCS to poll (``[outputs.modbus]``).

An asyncio TCP server on its own port (loopback unless configured) holds one block of
input registers (function code 4), laid out in docs/interface.md section 7 and in
:data:`REGISTERS`: the outlet and inlet moisture with their standard deviations [kg/kg dry
basis] and in % on the display basis, the window end [s since the epoch, UTC], the health
code, a counter of estimates and whether a lab result corrected this window. Floats are
IEEE-754 float32, high word first (ABCD), integers unsigned and big-endian; an estimate that
is missing is NaN with the health code saying why.

The protocol is :mod:`softsensor.outputs.modbus_protocol` (sans I/O): function code 4 only,
every other code exception 1, a bad count or a malformed read exception 3, pipelined requests
answered in order. This module moves bytes and keeps the connections in bounds, which
pymodbus' server did not (issue 40: 2,000 idle clients held 2,036 descriptors, two requests in
one segment got one answer, and a request to unit 0 logged a traceback with a frame dump):

* a connection without a request for ``idle_timeout_s`` (60 s) is closed (bytes that do
  not complete a request do not count: issue 49);
* at most ``max_connections`` (32) are open: a new one closes one of the address holding the
  most connections (the oldest that never sent a request, else the one idle longest), never
  one of the plant's own clients (``plant_clients``) for another address; a new one from
  elsewhere when only they hold slots is closed (:func:`evictee`; issue 49: a peer keeping 31
  busy connections got the DCS evicted before each of its polls);
* a client that does not read its answers is not read from until it does;
* a connection is answered at most :data:`TURN_BUDGET` requests per turn of the event loop
  and ``max_requests_per_s`` (100) a second, bursts of :data:`BURST_S` seconds' worth
  allowed: the server shares the daemon's event loop with the PLC poller, which a flood of
  valid reads must not starve (issue 49: four clients sending 256 kB reads stopped the scans).

The softsensor's Modbus client to the PLC is a different program path and never writes either.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import math
import os
import struct
import threading
import time
from collections import Counter
from collections.abc import Mapping
from typing import Any, Protocol, TypeVar

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.modbus_protocol import FramingError, RegisterProtocol
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
#: The kernel's queue before accept.
LISTEN_BACKLOG = 128
#: The server's abuse counters, by attribute: what each counts (``/metrics`` and health).
ABUSE_COUNTERS: dict[str, str] = {
    "refused": "Modbus requests answered with an exception (writes, other tables)",
    "framing_errors": "Modbus connections closed for bytes that are not Modbus TCP",
    "evicted": "Modbus connections closed to make room for a new one",
    "idle_closed": "Modbus connections closed after idle_timeout_s without a request",
    "refused_connections": "Modbus connections refused (every slot held by plant clients)",
}
#: Requests of one connection answered in one turn of the event loop at most.
TURN_BUDGET = 32
#: A connection's bucket holds this many seconds of ``max_requests_per_s`` (a burst).
BURST_S = 10.0


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


def _normal(address: str) -> str:
    """An IP address in one spelling (an IPv4-mapped IPv6 address as IPv4)."""
    try:
        ip = ipaddress.ip_address(address.split("%")[0])
    except ValueError:
        return address
    mapped = getattr(ip, "ipv4_mapped", None)
    return str(mapped or ip)


class _Slot(Protocol):
    address: str
    answered: bool
    last_active: float


S = TypeVar("S", bound=_Slot)


def evictee(open_: list[S], newcomer: str, plant: frozenset[str]) -> S | None:
    """The connection to close for a new one from ``newcomer`` when every slot is taken:
    one of the plant's clients (``plant``) only for another of them and when they hold every
    slot; among the others, one
    of the address holding the most (a peer keeping many busy connections gives up its own,
    not the DCS's one), the one that never sent a request first, else the one idle longest.
    None: only the plant's clients hold slots and the newcomer is not one (it is refused)."""
    pool = [c for c in open_ if c.address not in plant]
    if not pool:
        if newcomer not in plant:
            return None
        pool = open_
    held = Counter(c.address for c in pool)
    return min(pool, key=lambda c: (-held[c.address], c.answered, c.last_active))


class _Connection(asyncio.Protocol):
    """One client: bytes to :class:`RegisterProtocol`, its answers back, in order.

    The requests are answered at most :data:`TURN_BUDGET` per turn of the event loop and at
    most ``max_requests_per_s`` a second (a token bucket holding :data:`BURST_S` seconds of
    them): while requests wait, the socket is not read, so a client flooding valid reads
    (a 256 kB read is 21,000 of them) costs the loop a bounded share and the PLC poller on
    the same loop keeps its pace (issue 49)."""

    def __init__(self, server: EstimateModbusServer) -> None:
        self.server = server
        self.protocol = RegisterProtocol(server.settings.unit_id, server.registers)
        self.transport: asyncio.Transport | None = None
        self.last_active = time.monotonic()
        self.answered = False  #: it has sent a request (a client, not just a socket)
        self.address = ""  #: the client's IP address
        rate = server.settings.max_requests_per_s
        self._rate, self._burst = rate, max(rate * BURST_S, float(TURN_BUDGET))
        self._tokens, self._filled = self._burst, time.monotonic()
        self._writing_paused = False  #: the kernel has not taken our answers
        self._backlog = False  #: requests wait for their turn (reading paused)
        self._turn: asyncio.Handle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.address = _normal(peer[0]) if peer else ""
        self.server._admit(self)

    def data_received(self, data: bytes) -> None:
        self._serve(data)

    def _allowance(self) -> int:
        """Requests this turn may answer: the per-turn budget and the bucket's whole tokens."""
        now = time.monotonic()
        self._tokens = min(self._burst, self._tokens + (now - self._filled) * self._rate)
        self._filled = now
        return min(TURN_BUDGET, int(self._tokens))

    def _serve(self, data: bytes = b"") -> None:
        """Answer the requests the budget allows; the rest wait for a later turn."""
        self._turn = None
        if self.transport is None:
            return
        allowed = self._allowance()
        try:
            answers = self.protocol.feed(data, max_requests=allowed)
        except FramingError:
            self.server.framing_errors += 1
            self.close()
            return
        finally:
            self.server.refused += self.protocol.refused
            self.protocol.refused = 0
        self._tokens -= len(answers)
        if answers:  # idle is measured from the last request, not the last byte
            self.last_active = time.monotonic()
            self.answered = True
            self.transport.write(b"".join(answers))
        if self.transport is None or self.transport.is_closing():
            return
        self._backlog = self.protocol.waiting
        if self._backlog:  # the next turn, or when the bucket holds a token again
            wait = 0.0 if self._tokens >= 1 else (1 - self._tokens) / self._rate
            loop = asyncio.get_running_loop()
            self._turn = loop.call_later(wait, self._serve) if wait > 0 \
                else loop.call_soon(self._serve)
        self._reading()

    def _reading(self) -> None:
        """Read the socket only while nothing waits: neither answers for the kernel nor
        requests for their turn."""
        t = self.transport
        if t is None or t.is_closing():
            return
        if self._writing_paused or self._backlog:
            if t.is_reading():
                t.pause_reading()
        elif not t.is_reading():
            t.resume_reading()

    # a client that sends requests without reading the answers: stop reading until the
    # kernel takes them, so its answers cannot pile up in memory
    def pause_writing(self) -> None:
        self._writing_paused = True
        self._reading()

    def resume_writing(self) -> None:
        self._writing_paused = False
        self._reading()

    def connection_lost(self, exc: Exception | None) -> None:
        self.server._open.pop(self, None)
        self.transport = None
        if self._turn is not None:
            self._turn.cancel()
            self._turn = None

    def close(self) -> None:
        """Close at once (the descriptor freed now, whatever is unsent)."""
        self.server._open.pop(self, None)
        if self.transport is not None:
            self.transport.abort()


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
        self.framing_errors = 0  #: connections closed for bytes that are not Modbus TCP
        self.idle_closed = 0  #: connections closed after ``idle_timeout_s`` without a request
        self.evicted = 0  #: connections closed to make room for a new one
        #: new connections closed at once (every slot held by the plant's clients)
        self.refused_connections = 0
        self._plant = frozenset(_normal(a) for a in settings.plant_clients)
        self._words = estimate_registers({}, 0, 0, display)
        self._lock = threading.Lock()  # the estimator's thread and the loop's write words
        self._open: dict[_Connection, None] = {}  # insertion order: the oldest first
        self._server: asyncio.Server | None = None
        self._sweeper: asyncio.Task | None = None
        self.port = settings.port

    def abuse(self) -> dict[str, int]:
        """What clients were refused or closed for, by counter (:data:`ABUSE_COUNTERS`)."""
        return {name: int(getattr(self, name)) for name in ABUSE_COUNTERS}

    @property
    def connections(self) -> int:
        """Connections open now."""
        return len(self._open)

    def registers(self) -> list[int]:
        """The register block served now."""
        return self._words

    def _admit(self, conn: _Connection) -> None:
        """A new connection; when ``max_connections`` are open, one is closed first (see
        :func:`evictee`), or the new one when only the plant's clients hold the slots."""
        if len(self._open) >= self.settings.max_connections:
            victim = evictee(list(self._open), conn.address, self._plant)
            if victim is None:
                self.refused_connections += 1
                conn.close()
                return
            self.evicted += 1
            victim.close()
        self._open[conn] = None

    async def _sweep(self) -> None:
        """Close connections idle for longer than ``idle_timeout_s``."""
        timeout = self.settings.idle_timeout_s
        while True:
            await asyncio.sleep(min(timeout / 4, 5.0))
            limit = time.monotonic() - timeout
            for conn in [c for c in self._open if c.last_active < limit]:
                self.idle_closed += 1
                conn.close()

    async def start(self) -> str:
        """Bind and serve; NaN estimates and health 3 until the first estimate. What it
        serves: ``modbus://host:port``."""
        s = self.settings
        loop = asyncio.get_running_loop()
        try:
            self._server = await loop.create_server(lambda: _Connection(self), s.host, s.port,
                                                    backlog=LISTEN_BACKLOG)
        except OSError as exc:  # asyncio words it "error while attempting to bind on ..."
            why = os.strerror(exc.errno) if exc.errno else str(exc)
            raise ConfigError(f"outputs.modbus: cannot listen on {s.host}:{s.port}: "
                              f"{why}") from exc
        self.port = self._server.sockets[0].getsockname()[1]
        self._sweeper = asyncio.create_task(self._sweep(), name="modbus-idle")
        log.info("estimate registers served on %s:%d", s.host, self.port)
        return f"modbus://{s.host}:{self.port}"

    def on_estimate(self, estimate: Estimate) -> None:
        """Serve a new estimate (any thread: the block is replaced whole)."""
        with self._lock:
            self.counter += 1
            self._words = estimate_registers(estimate.to_body(), estimate.time_ns,
                                             self.counter, self.display)

    def on_health(self, health: Health) -> None:
        """A health change between estimates (e.g. ``stale`` when scans stop): register 14."""
        with self._lock:
            words = list(self._words)
            words[REGISTERS["health"][0]] = HEALTH_CODES.get(health.status, NO_ESTIMATE)
            self._words = words

    def on_lab(self, lab: LabResult) -> None:
        """Lab results are not served as registers."""

    async def stop(self) -> None:
        server, self._server = self._server, None
        if self._sweeper is not None:
            self._sweeper.cancel()
            self._sweeper = None
        if server is not None:
            server.close()
        for conn in list(self._open):
            conn.close()
        if server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(server.wait_closed(), 5.0)


__all__ = ["ABUSE_COUNTERS", "BURST_S", "HEALTH_CODES", "LISTEN_BACKLOG", "N_REGISTERS",
           "NO_ESTIMATE", "REGISTERS", "TURN_BUDGET", "EstimateModbusServer",
           "estimate_registers", "evictee"]
