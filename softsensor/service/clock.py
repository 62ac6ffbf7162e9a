"""The daemon's plant clock: the wall clock, a scaled clock for accelerated demos, or the
PLC's own clock.

At ``time_scale = 1`` the daemon's clock is the wall clock. At ``N > 1`` it runs N times faster
from ``clock_start`` (default now; after a restart not before the checkpoint's time), the
poller polls N times as often and its frozen-value and back-off timers run on the same scaled
clock, so a daemon follows ``softsensor plant-server --speed N`` window for window. With
``clock_start = "plc"`` (``--clock-start plc``) the clock starts at the PLC's own clock (the
tag map's ``[clock]`` registers, which the virtual PLC serves from its plant), read once at
start (:func:`read_plc_clock`) and carried forward by the time since: the demo's plant and
daemon then share one clock, and the lab files the plant drops (stamped on its clock) are not
"sampled after they arrived" because the daemon started later.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from softsensor.errors import ConfigError, IngestError
from softsensor.ingest.modbus_poller import ModbusPoller
from softsensor.ingest.tagmap import TagMap
from softsensor.messages import iso_utc
from softsensor.service.day_replay import parse_time
from softsensor.service.logs import event
from softsensor.service.settings import ServiceSettings

log = logging.getLogger(__name__)


async def _no_sink(*_scan: Any) -> None:
    """The clock read at start hands no scans on."""


class ScaledClock:
    """Plant time: ``start_ns + (monotonic() - m0) * scale`` [ns since the epoch, UTC].

    With ``scale == 1`` and no ``start_ns`` it is the wall clock itself.
    """

    def __init__(self, scale: float = 1.0, start_ns: int | None = None, *,
                 wall_ns: Callable[[], int] = time.time_ns,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        if not scale > 0:
            raise ConfigError(f"service.time_scale must be > 0, got {scale!r}")
        self.scale = float(scale)
        self._wall = wall_ns
        self._mono = monotonic
        self._m0 = monotonic()
        self.start_ns = int(wall_ns() if start_ns is None else start_ns)
        self.is_wall = scale == 1.0 and start_ns is None

    def now_ns(self) -> int:
        """Current plant time [ns]."""
        if self.is_wall:
            return self._wall()
        return self.start_ns + int(round((self._mono() - self._m0) * self.scale * 1e9))

    def monotonic(self) -> float:
        """Scaled monotonic time [plant s] (for the poller's frozen check and back-off)."""
        return (self._mono() - self._m0) * self.scale


#: Longest wait for the PLC's clock at start (``clock_start = "plc"``) [s, wall].
PLC_CLOCK_WAIT_S = 30.0
#: A checkpoint's time further than this past the clock start is not trusted [ns].
MAX_RESUME_JUMP_NS = 30 * 86_400 * 10**9


def daemon_clock(settings: ServiceSettings, plc_clock: tuple[int, float] | None,
                 saved_at_ns: int | None) -> ScaledClock:
    """The daemon's clock (module docstring): the PLC's (``plc_clock``: its time [ns] and when
    it was read [monotonic s]) carried forward, or the configured start, not before a resumed
    checkpoint's time ``saved_at_ns`` [ns] when time is accelerated."""
    s = settings
    if plc_clock is not None:  # the PLC's clock, carried forward since it was read
        plc_ns, read_at = plc_clock
        start = plc_ns + int(round((time.monotonic() - read_at) * s.time_scale * 1e9))
        return ScaledClock(s.time_scale, start)
    start = parse_time(s.clock_start, "service.clock_start")
    if s.time_scale != 1.0:
        start = time.time_ns() if start is None else start
        if saved_at_ns is not None and saved_at_ns > start + MAX_RESUME_JUMP_NS:
            event(log, "checkpoint_time_ignored", logging.WARNING, saved_at_ns=saved_at_ns,
                  reason="more than 30 days after the clock start")
        elif saved_at_ns is not None and saved_at_ns > start:
            start = saved_at_ns  # accelerated time must not run backwards over a restart
    return ScaledClock(s.time_scale, start)


async def read_plc_clock(tagmap: TagMap, time_scale: float) -> tuple[int, float]:
    """The PLC's clock [ns] and when it was read [monotonic s] (module docstring)."""
    poller = ModbusPoller(tagmap, _no_sink)
    try:
        ns = await poller.read_clock(PLC_CLOCK_WAIT_S)
    except IngestError as exc:
        raise ConfigError(f"service.clock_start = \"plc\": {exc}") from exc
    finally:
        poller.close()
    event(log, "plc_clock", plc_time=iso_utc(ns), time_scale=time_scale)
    return ns, time.monotonic()


__all__ = ["MAX_RESUME_JUMP_NS", "PLC_CLOCK_WAIT_S", "ScaledClock", "daemon_clock",
           "read_plc_clock"]
