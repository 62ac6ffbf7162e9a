"""The Modbus poller: reads the PLC every scan period and hands each scan to a sink.

Read-only by construction: the only Modbus requests this module makes are in
:meth:`ModbusPoller._read`, which calls ``read_holding_registers`` (function code 3) or
``read_input_registers`` (function code 4) and nothing else. ``tests/ingest/test_modbus_poller.py``
checks that no other client method is called anywhere in this file.

Every scan yields ``(time_ns, body, quality)``:

- ``time_ns``: wall-clock time of the scan's start [ns since the Unix epoch, UTC];
- ``body``: the ``/plant/scan`` JSON body (CONTRACT section 2): every signal of the tag map,
  its SI value, or ``None`` where the value is bad;
- ``quality``: ``{signal: reason}`` for the bad ones. A reason is ``"<kind>: <detail>"`` with
  kind one of ``not_connected``, ``no_response``, ``exception_reply``, ``read_failed``,
  ``not_finite``, ``out_of_range``, ``frozen``.

A value is bad when it cannot be read (no connection, timeout, exception reply), is not finite,
lies outside the tag's valid range, or has kept the same register words (bit for bit) longer
than ``frozen_after_s``. Bad values are never published as numbers.

Connection handling: pymodbus' own reconnect is switched off (it only retries after a lost
connection, not after a failed first connect); the poller reconnects at scan time with a back-off
that doubles from ``reconnect_delay_s`` to ``reconnect_delay_max_s`` and resets on success.
Every await is bounded: a read by ``timeout_s * (retries + 1)`` plus a margin, a connect by
``timeout_s``, the sink by one poll period.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import NamedTuple

from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from softsensor.errors import IngestError
from softsensor.ingest.registers import decode_raw, raw_to_si
from softsensor.ingest.tagmap import ReadRequest, TagMap, TagSpec, group_reads
from softsensor.log_throttle import Throttle, outside_text

log = logging.getLogger(__name__)

#: ``await sink(time_ns, body, quality)``
Sink = Callable[[int, dict[str, float | None], dict[str, str]], Awaitable[None]]

_EXCEPTION_NAMES = {1: "illegal function", 2: "illegal address", 3: "illegal value",
                    4: "device failure", 5: "acknowledge", 6: "device busy",
                    10: "gateway path unavailable", 11: "gateway target no response"}


class Scan(NamedTuple):
    """One scan: time [ns, UTC], ``/plant/scan`` body (SI, None where bad), bad reasons."""

    time_ns: int
    body: dict[str, float | None]
    quality: dict[str, str]


@dataclass
class PollerStats:
    """Counters, for health reporting and tests."""

    scans: int = 0
    reads: int = 0  #: read requests sent (FC 3 and FC 4 only)
    read_failures: int = 0
    connect_attempts: int = 0
    connects: int = 0
    sink_failures: int = 0
    overruns: int = 0  #: scans that took longer than one period


class _ReadFailed(Exception):
    def __init__(self, reason: str, connection_lost: bool = False):
        super().__init__(reason)
        self.reason = reason
        self.connection_lost = connection_lost


@dataclass
class _Seen:
    words: tuple[int, ...]
    since: float  # monotonic time these words were first seen [s]


def _short(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text[:120]


class ModbusPoller:
    """Polls the PLC described by ``tagmap`` and awaits ``sink(time_ns, body, quality)``.

    Parameters
    ----------
    tagmap
        Where the PLC is, what to read and how to decode it.
    sink
        Async callable given every scan; an exception or a timeout (one period) in it is
        logged and counted, and polling goes on.
    clock_ns, monotonic
        Wall clock [ns] for scan times and monotonic clock [s] for frozen checks and the
        back-off; injectable for tests.
    """

    def __init__(self, tagmap: TagMap, sink: Sink, *,
                 clock_ns: Callable[[], int] = time.time_ns,
                 monotonic: Callable[[], float] = time.monotonic):
        self.tagmap = tagmap
        self.settings = tagmap.modbus
        self.sink = sink
        self.stats = PollerStats()
        self._clock_ns = clock_ns
        self._monotonic = monotonic
        self._requests: list[ReadRequest] = group_reads(tagmap)
        self._signals = tagmap.signals
        s = self.settings
        self._client = AsyncModbusTcpClient(
            s.host, port=s.port, timeout=s.timeout_s, retries=s.retries,
            reconnect_delay=0, reconnect_delay_max=0)  # reconnects are ours, see module doc
        self._read_deadline = s.timeout_s * (s.retries + 1) + 0.5
        self._backoff = s.reconnect_delay_s
        self._next_connect = -math.inf
        self._disconnected = f"not_connected: no connection to {s.host}:{s.port} yet"
        self._seen: dict[str, _Seen] = {}
        self._bad: dict[str, str] = {}
        self._throttle = Throttle()

    @property
    def connected(self) -> bool:
        """True while the TCP connection to the PLC is up."""
        return self._client.connected

    @property
    def requests(self) -> list[ReadRequest]:
        """The read requests one scan makes (see :func:`~softsensor.ingest.tagmap.group_reads`)."""
        return list(self._requests)

    def close(self) -> None:
        """Close the connection (the next scan reconnects)."""
        self._client.close()

    # -- connection -----------------------------------------------------------------------

    async def _ensure_connected(self, now: float) -> bool:
        if self._client.connected:
            return True
        if now < self._next_connect:
            return False
        s = self.settings
        self.stats.connect_attempts += 1
        ok = False
        with contextlib.suppress(TimeoutError, OSError, ModbusException):
            ok = await asyncio.wait_for(self._client.connect(), s.timeout_s + 0.5)
        if ok and self._client.connected:
            self.stats.connects += 1
            self._backoff = s.reconnect_delay_s
            log.info("connected to PLC %s:%d", s.host, s.port)
            return True
        delay = self._backoff
        self._next_connect = now + delay
        self._backoff = min(2 * delay, s.reconnect_delay_max_s)
        self._disconnected = (f"not_connected: cannot connect to {s.host}:{s.port} "
                              f"(next attempt in {delay:g} s)")
        log.warning("PLC %s:%d unreachable; next attempt in %g s", s.host, s.port, delay)
        return False

    # -- the only Modbus requests of the poller: FC 3 and FC 4 -----------------------------

    async def _read(self, req: ReadRequest) -> list[int]:
        """Read one request's registers; raises :class:`_ReadFailed` with a reason."""
        self.stats.reads += 1
        try:
            if req.table == "holding":  # function code 3
                pending = self._client.read_holding_registers(
                    req.address, count=req.count, device_id=req.unit_id)
            else:  # "input": function code 4
                pending = self._client.read_input_registers(
                    req.address, count=req.count, device_id=req.unit_id)
            rr = await asyncio.wait_for(pending, self._read_deadline)
        except ConnectionException as exc:
            raise _ReadFailed(f"not_connected: {_short(exc)}", connection_lost=True) from exc
        except (ModbusIOException, TimeoutError) as exc:
            raise _ReadFailed(f"no_response: {_short(exc)}",
                              connection_lost=not self._client.connected) from exc
        except (ModbusException, OSError) as exc:
            raise _ReadFailed(f"read_failed: {_short(exc)}",
                              connection_lost=not self._client.connected) from exc
        if rr.isError():
            code = getattr(rr, "exception_code", None)
            name = _EXCEPTION_NAMES.get(code or 0, "unknown")
            raise _ReadFailed(f"exception_reply: code {code} ({name}) from unit {req.unit_id} "
                              f"FC {req.function_code} at {req.address}+{req.count}")
        regs = list(getattr(rr, "registers", []))
        if len(regs) != req.count:
            raise _ReadFailed(f"read_failed: asked {req.count} registers, got {len(regs)}")
        return regs

    async def read_clock(self, timeout_s: float) -> int:
        """The PLC's clock (the tag map's ``[clock]`` registers) [ns since the epoch]; tried
        until ``timeout_s`` [wall s] has passed (a PLC still starting), then
        :class:`IngestError` saying why. Read through ``_read``, like every value."""
        c = self.tagmap.clock
        if c is None:
            raise IngestError(f"{self.tagmap.source}: has no [clock] table, so the PLC's "
                              "clock cannot be read (service.clock_start = \"plc\")")
        req = ReadRequest(c.unit_id, c.table, c.address, c.count, ())
        deadline = time.monotonic() + timeout_s
        why = "no attempt"
        while True:
            if await self._ensure_connected(time.monotonic()):
                try:
                    hi, lo = await self._read(req)
                    return (hi << 16 | lo) * 10**9
                except _ReadFailed as f:
                    why = f.reason
            else:
                why = self._disconnected
            if time.monotonic() >= deadline:
                raise IngestError(f"the PLC's clock ({c.table} registers {c.address}-"
                                  f"{c.address + 1} of unit {c.unit_id}) not read within "
                                  f"{timeout_s:g} s: {why}")
            self._next_connect = -math.inf
            await asyncio.sleep(1.0)

    async def _read_all(self) -> tuple[dict[str, list[int]], dict[str, str]]:
        """Registers per signal, and reasons for the signals that could not be read."""
        words: dict[str, list[int]] = {}
        failed: dict[str, str] = {}
        lost: str | None = None
        for req in self._requests:
            if lost is not None:
                failed.update((t.signal, lost) for t in req.tags)
                continue
            try:
                regs = await self._read(req)
            except _ReadFailed as f:
                self.stats.read_failures += 1
                if f.connection_lost:
                    lost = f.reason
                    failed.update((t.signal, f.reason) for t in req.tags)
                    self._next_connect = -math.inf  # reconnect at the next scan
                elif len(req.tags) > 1 and f.reason.startswith("exception_reply"):
                    # one bad tag (or a bridged gap) must not blank its neighbours
                    w, bad = await self._read_singly(req.tags)
                    words.update(w)
                    failed.update(bad)
                else:
                    failed.update((t.signal, f.reason) for t in req.tags)
                continue
            for t in req.tags:
                words[t.signal] = regs[req.slice(t)]
        return words, failed

    async def _read_singly(self, tags: tuple[TagSpec, ...]
                           ) -> tuple[dict[str, list[int]], dict[str, str]]:
        words: dict[str, list[int]] = {}
        failed: dict[str, str] = {}
        for t in tags:
            one = ReadRequest(t.unit_id, t.table, t.address, t.count, (t,))
            try:
                words[t.signal] = await self._read(one)
            except _ReadFailed as f:
                self.stats.read_failures += 1
                failed[t.signal] = f.reason
        return words, failed

    # -- quality --------------------------------------------------------------------------

    def _evaluate(self, tag: TagSpec, regs: list[int], now: float) -> tuple[float | None, str]:
        """SI value of ``tag``, or None and the reason it is bad."""
        key = tuple(regs)
        seen = self._seen.get(tag.signal)
        if seen is None or seen.words != key:
            seen = self._seen[tag.signal] = _Seen(key, now)
        try:
            raw = decode_raw(regs, tag.data_type, tag.word_order, tag.byte_order)
        except IngestError as exc:
            return None, f"read_failed: {exc}"
        si = raw_to_si(raw, tag)
        if not math.isfinite(si):
            return None, f"not_finite: {raw!r}"
        if not tag.valid_min <= si <= tag.valid_max:
            return None, (f"out_of_range: {si:.6g} {tag.si_unit} outside "
                          f"[{tag.valid_min:g}, {tag.valid_max:g}]")
        limit = (self.settings.frozen_after_s if tag.frozen_after_s is None
                 else tag.frozen_after_s)
        age = now - seen.since
        if limit > 0 and age > limit:
            return None, f"frozen: unchanged for {age:.0f} s (limit {limit:g} s)"
        return float(si), ""

    # -- scanning -------------------------------------------------------------------------

    async def scan_once(self) -> Scan:
        """Read every tag once and return the scan (does not call the sink)."""
        time_ns = self._clock_ns()
        now = self._monotonic()
        self.stats.scans += 1
        if await self._ensure_connected(now):
            words, failed = await self._read_all()
        else:
            words, failed = {}, {s: self._disconnected for s in self._signals}
        body: dict[str, float | None] = {}
        quality: dict[str, str] = {}
        for sig in self._signals:
            if sig in words:
                value, reason = self._evaluate(self.tagmap.tag(sig), words[sig], now)
            else:
                value, reason = None, failed.get(sig, "read_failed: not read")
            body[sig] = value
            if reason:
                quality[sig] = reason
        self._log_changes(quality)
        return Scan(time_ns, body, quality)

    def _log_changes(self, quality: dict[str, str]) -> None:
        # a flapping sensor changes every scan: its lines are rate-limited per signal
        for sig in self._signals:
            old, new = self._bad.get(sig), quality.get(sig)
            if new and (old is None or old.split(":")[0] != new.split(":")[0]):
                self._throttle.log(log, f"bad {sig}", logging.WARNING, "%s bad: %s", sig,
                                   outside_text(new))
            elif old and not new:
                self._throttle.log(log, f"good {sig}", logging.INFO, "%s good again", sig)
        self._bad = dict(quality)

    async def run(self, stop: asyncio.Event) -> None:
        """Scan every ``poll_period_s`` and await the sink, until ``stop`` is set.

        Scans keep a fixed cadence; a scan that overruns skips the missed ticks. The
        connection is closed on return.
        """
        period = self.settings.poll_period_s
        loop = asyncio.get_running_loop()
        next_t = loop.time()
        try:
            while not stop.is_set():
                scan = await self.scan_once()
                try:
                    await asyncio.wait_for(self.sink(*scan), period)
                except Exception:  # the sink's failure must not stop the polling
                    self.stats.sink_failures += 1
                    self._throttle.log(log, "sink", logging.ERROR, "scan sink failed",
                                       exc_info=True)
                next_t += period
                now = loop.time()
                if next_t <= now:
                    self.stats.overruns += 1
                    next_t += math.ceil((now - next_t) / period) * period
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(stop.wait(), next_t - now)
        finally:
            self.close()
