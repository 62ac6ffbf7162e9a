"""The daemon's own PLC scans told apart from other senders' scans on the bus.

Zenoh does not say who put a message, and the bus is open by default: a peer's flood of
scans went through the same rate limit, the same recording cap and the same windows as the
PLC's (issue 40: a flood spent the day's 8 MB cap in under a second at 60x, after which no
real scan was recorded for the rest of the day, and a 30 s flood's ``T_air_in = 480`` values
were averaged into the windows). The daemon knows its own scans: the poller's publisher tells
:meth:`PlcScans.sent` each one before it goes on the bus, and when it comes back from the bus
:meth:`PlcScans.origin` recognises it by its time and body. The worker then admits the PLC's
scans ahead of any other sender (no shared rate limit, recorded under their own cap), and
refuses other senders' scans while the PLC's are arriving (:data:`HOLD_SCANS` poll periods
since the last one), so they cannot write values into a window. Without a PLC (a daemon fed by
a peer on the bus, or the PLC down) other senders' scans are taken as before.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any

from softsensor.bus.transport import BusMessage

#: Poll periods after the PLC's last scan during which other senders' scans are refused.
HOLD_SCANS = 3
#: Own scans remembered until they come back from the bus (a bound, not a working size).
MAX_PENDING = 1000
PLC, OTHER, REFUSED = "plc", "other", "refused"


def _key(time_ns: int, body: Mapping[str, Any]) -> tuple[int, str]:
    """A scan's identity: its time and its values as JSON (as the bus carries them)."""
    return int(time_ns), json.dumps({k: v for k, v in body.items() if k != "time_ns"},
                                    sort_keys=True, separators=(",", ":"))


class PlcScans:
    """Recognises the daemon's own scans (module docstring).

    Parameters
    ----------
    clock_ns : callable
        The daemon's clock [ns, plant time].
    scan_period_s : float
        The poller's period [s, plant time].
    hold_scans : float
        Poll periods after the PLC's last scan during which other senders' scans are refused
        (0: never; ``[service] plc_scans_first = false``).
    """

    def __init__(self, clock_ns: Callable[[], int], scan_period_s: float,
                 hold_scans: float = HOLD_SCANS) -> None:
        self.clock_ns = clock_ns
        self.hold_ns = int(hold_scans * scan_period_s * 1e9)
        self._pending: OrderedDict[tuple[int, str], None] = OrderedDict()
        self._last_plc_ns: int | None = None
        self._lock = threading.Lock()  # the poller's loop adds, Zenoh's thread looks up

    def sent(self, time_ns: int, body: Mapping[str, Any]) -> None:
        """The poller is about to put this scan on the bus."""
        with self._lock:
            self._pending[_key(time_ns, body)] = None
            while len(self._pending) > MAX_PENDING:
                self._pending.popitem(last=False)

    def origin(self, message: BusMessage) -> str:
        """:data:`PLC` for the daemon's own scan, :data:`REFUSED` for another sender's scan
        while the PLC's arrive, else :data:`OTHER` (lab results: always)."""
        if message.kind != "scan" or message.time_ns is None:
            return OTHER
        key = _key(message.time_ns, message.body)
        with self._lock:
            if key in self._pending:
                del self._pending[key]
                self._last_plc_ns = self.clock_ns()
                return PLC
            last = self._last_plc_ns
        if self.hold_ns > 0 and last is not None and self.clock_ns() - last <= self.hold_ns:
            return REFUSED
        return OTHER


__all__ = ["HOLD_SCANS", "OTHER", "PLC", "REFUSED", "PlcScans"]
