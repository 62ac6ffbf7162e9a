"""The OPC UA output's connections kept by the Modbus output's rules, which asyncua lacks.

asyncua refuses a connection beyond its ``max_connections`` and evicts no one, so 32
sessions from any client locked every other out (issue 49: 0 of 36 fresh reads), and a
session it closes for inactivity keeps its TCP connection (open past 90 s after a 60 s
timeout). :class:`OpcUaConnections` runs beside the server, on its loop, and every
:data:`SWEEP_S`:

* closes the TCP connection of a session idle (no request) for longer than ``idle_timeout_s``
  or closed by asyncua;
* while more than ``max_connections`` are open (asyncua admits :data:`HEADROOM` more, so a
  newcomer is seen), closes one by the Modbus output's rule
  (:func:`~softsensor.outputs.modbus_server.evictee`): one of the address holding the most
  connections, the one without a session first, else the one idle longest; never one of the
  plant's own clients (``plant_clients``) for another address, whose newcomer is closed
  instead when only they hold the slots.

The standard address space (about 58 MB of Python objects, 17-22 s to build on the
development machine) is read from a shelf on disk instead, nodes loaded as they are asked
for (asyncua's ``shelf_file``), which :func:`standard_space_shelf` keeps beside the package
like numba's cache: the first start builds it, later ones take 2 MB (issue 49: 383 MB
resident with the four outputs).

It reads asyncua's ``BinaryServer.clients`` (each an ``OPCUAProtocol`` with its
``transport``, ``peer_name`` and ``processor``): asyncua 2.1's names, checked by
``tests/outputs/test_opcua_server.py``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from softsensor.outputs.modbus_server import _normal, evictee
from softsensor.outputs.settings import OpcUaSettings

log = logging.getLogger(__name__)

#: How often the connections are looked at [s].
SWEEP_S = 0.2
#: Connections asyncua admits beyond ``max_connections``, so a newcomer can displace one.
HEADROOM = 4


@dataclass
class _Slot:
    """One asyncua connection as :func:`evictee` reads it."""

    protocol: Any
    address: str
    answered: bool  #: it has a session
    last_active: float

    @classmethod
    def of(cls, protocol: Any, opened: float) -> _Slot:
        peer = getattr(protocol, "peer_name", None)
        proc = getattr(protocol, "processor", None)
        last = None if proc is None else getattr(proc, "session_last_activity", None)
        session = None if proc is None else getattr(proc, "session", None)
        return cls(protocol, _normal(peer[0]) if peer else "", session is not None,
                   opened if last is None else last)


def standard_space_shelf(folder: Path | None = None) -> tuple[Path | None, Callable[[], None]]:
    """Where asyncua's standard address space is shelved, and what to call once the server
    has initialised; ``(None, no-op)`` where no folder can be written (then asyncua builds
    it in memory, as before).

    A shelf is built in a folder of this process and renamed into place whole, so a
    concurrent start or a killed one never leaves half a shelf; it is marked complete by an
    empty file at its path, which asyncua checks (``dbm.dumb``, the one ``dbm`` everywhere,
    names its files ``<path>.dat`` and ``<path>.dir``)."""
    import asyncua

    base = folder or Path(__file__).parent / "__pycache__"
    ready = base / f"opcua-aspace-{getattr(asyncua, '__version__', 'x')}"
    if (ready / "aspace").is_file():
        return ready / "aspace", lambda: None
    building = base / f"{ready.name}.tmp-{os.getpid()}"
    try:
        building.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None, lambda: None

    def done() -> None:
        shelf = building / "aspace"
        try:
            if not shelf.exists() and any(building.glob("aspace.*")):
                shelf.touch()  # complete: asyncua reads it from now on
            if shelf.is_file():
                os.rename(building, ready)
                return
        except OSError:  # another start put one in place first
            pass
        shutil.rmtree(building, ignore_errors=True)

    return building / "aspace", done


class OpcUaConnections:
    """Sweeps the connections of asyncua's binary server ``bserver`` (module docstring)."""

    def __init__(self, bserver: Any, settings: OpcUaSettings) -> None:
        self.bserver = bserver
        self.settings = settings
        self._plant = frozenset(_normal(a) for a in settings.plant_clients)
        self._opened: dict[int, float] = {}  # id(protocol) -> when first seen
        self.evicted = 0  #: connections closed to make room for a newer one
        self.refused_connections = 0  #: newcomers closed (only plant clients held slots)
        self.idle_closed = 0  #: connections of sessions idle or closed by asyncua

    def _open(self) -> list[Any]:
        return [p for p in list(self.bserver.clients)
                if p.transport is not None and not p.transport.is_closing()]

    @staticmethod
    def _close(protocol: Any) -> None:
        with contextlib.suppress(Exception):
            protocol.transport.abort()

    def sweep(self, now: float | None = None) -> None:
        """One look at the connections (module docstring)."""
        now = time.monotonic() if now is None else now
        open_ = self._open()
        self._opened = {id(p): self._opened.get(id(p), now) for p in open_}
        limit = now - self.settings.idle_timeout_s
        for p in list(open_):
            proc = p.processor
            last = getattr(proc, "session_last_activity", None)
            session = getattr(proc, "session", None)
            closed = session is not None and getattr(session.state, "name", "") == "Closed"
            if (last is not None and last < limit) or closed:
                self.idle_closed += 1
                self._close(p)
                open_.remove(p)
        while len(open_) > self.settings.max_connections:
            newcomer = open_[-1]
            slots = [_Slot.of(p, self._opened[id(p)]) for p in open_[:-1]]
            victim = evictee(slots, _Slot.of(newcomer, now).address, self._plant)
            if victim is None:
                self.refused_connections += 1
                gone = newcomer
            else:
                self.evicted += 1
                gone = victim.protocol
            self._close(gone)
            open_.remove(gone)

    async def run(self) -> None:
        """Sweep every :data:`SWEEP_S` until cancelled."""
        while True:
            await asyncio.sleep(SWEEP_S)
            try:
                self.sweep()
            except Exception:  # noqa: BLE001 - asyncua's internals changed: said, not fatal
                log.exception("OPC UA connection sweep failed")
                return


__all__ = ["HEADROOM", "SWEEP_S", "OpcUaConnections", "standard_space_shelf"]
