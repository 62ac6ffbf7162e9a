"""The daemon's producer side: the Modbus poller's scans onto the bus.

:class:`ScanPublisher` is the poller's sink (:class:`~softsensor.ingest.modbus_poller.
ModbusPoller` awaits it with each scan): it publishes the scan on ``plant/<unit>/scan``, whence
the daemon's consumer (:mod:`.bus_worker`) and recorder take it, knowing it for the PLC's
(:mod:`.plc_scans`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from softsensor.bus.zenoh_bus import Publisher


class ScanPublisher:
    """The poller's sink: publishes each scan on ``plant/<unit>/scan``.

    Bad values are ``null`` in the body (CONTRACT section 2); the poller's reasons go along
    under ``quality`` (``{signal: "<kind>: detail"}``) when there are any.
    """

    def __init__(self, publisher: Publisher,
                 on_sent: Callable[[int, dict[str, Any]], None] | None = None) -> None:
        self.publisher = publisher
        self.on_sent = on_sent  # told each scan first (the daemon knows its own scans by it)
        self.n_published = 0

    async def __call__(self, time_ns: int, body: dict[str, float | None],
                       quality: dict[str, str]) -> None:
        msg: dict[str, Any] = dict(body)
        if quality:
            msg["quality"] = dict(quality)
        if self.on_sent is not None:
            self.on_sent(time_ns, msg)
        self.publisher.put("scan", msg, time_ns)
        self.n_published += 1


__all__ = ["ScanPublisher"]
