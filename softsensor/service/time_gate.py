"""Time sanity at the daemon's edges: a message stamped far from the daemon's clock is refused.

One scan stamped two days ahead, from any peer on the bus, used to tick 288 stale windows at
once and then have every real scan dropped as late for two days; one stamped ``-5`` broke the
recorder's open chunk. A :class:`TimeGate` compares a message's time with the service clock:
more than ``max_future_s`` ahead or ``max_past_s`` behind is refused with a reason, counted by
the caller (``refused_time`` in the health body, the recorder's ``refused``), never ticked and
never recorded. Offline (a replayed day has no clock) only the absolute bound applies: no time
before 2000, which no plant recorded and which is the mark of seconds or ms given for ns.
"""

from __future__ import annotations

from collections.abc import Callable

from softsensor.messages import EARLIEST_SAMPLE_NS

NS = 10**9


class TimeGate:
    """``gate(t)`` is None for a plausible time [ns since the epoch], else the reason."""

    def __init__(self, clock: Callable[[], int] | None, max_future_s: float = 300.0,
                 max_past_s: float = 6 * 3600.0) -> None:
        self.clock = clock
        self.max_future_ns = int(max_future_s * NS)
        self.max_past_ns = int(max_past_s * NS)

    def __call__(self, t_ns: int) -> str | None:
        if t_ns < EARLIEST_SAMPLE_NS:
            return f"time {t_ns} ns is before 2000 (s or ms given for ns?)"
        if self.clock is None:
            return None
        now = self.clock()
        if t_ns > now + self.max_future_ns:
            return f"time is {(t_ns - now) / NS:.0f} s ahead of the daemon's clock"
        if t_ns < now - self.max_past_ns:
            return f"time is {(now - t_ns) / NS:.0f} s behind the daemon's clock"
        return None


__all__ = ["TimeGate"]
