"""An in-process bus: the worker's input and output sides without a network.

A :class:`MemoryBus` stands for the Zenoh bus of one unit inside one process, as httpx's
``MockTransport`` stands for the network: :meth:`MemoryBus.put` hands the message at once, on
the caller's thread, to every subscriber of its kind, in the order they subscribed. Nothing
is queued, encoded or waited for, so what one thread puts is received in the order it was put,
and when ``put`` returns every subscriber has it. ``replay`` runs the estimator's worker on
one (:class:`MemoryInput`, :class:`MemoryOutput`), its recorder subscribed beside it.

Each subscriber gets its own copy of the top-level body, with ``time_ns`` added as a Zenoh
payload carries it; the values inside are handed over as they are (a recorded day's bodies are
JSON already), so a subscriber must not change nested values it did not make. A message's
``nbytes`` (the length of the JSON payload it would be on Zenoh) is measured only for a
subscriber that asks for it: an encoding per message.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from softsensor.bus.transport import INPUT_KINDS, KINDS, BusMessage, Receive, encode_payload
from softsensor.signals import zenoh_key


class MemorySubscription:
    """A subscriber of a :class:`MemoryBus` (made by :meth:`MemoryBus.subscribe`).

    ``n_received`` counts the messages handed to its callback. An exception in the callback
    reaches the one who put the message (in one process, the sender should know).
    """

    def __init__(self, bus: MemoryBus, callback: Receive, kinds: Iterable[str], *,
                 max_bytes: int | None = None, on_too_large: Callable[[], None] | None = None,
                 sized: bool = False) -> None:
        self.bus = bus
        self.kinds = frozenset(kinds)
        self.max_bytes = max_bytes
        self.sized = sized or max_bytes is not None
        self.n_received = 0
        self.n_errors = 0  # (a message put in memory is never malformed: kept for the interface)
        self._callback = callback
        self._on_too_large = on_too_large

    def deliver(self, kind: str, key: str, body: dict[str, Any], time_ns: int) -> None:
        """Hand one message to the callback (called by :meth:`MemoryBus.put`)."""
        nbytes = len(encode_payload(body, time_ns)) if self.sized else 0
        if self.max_bytes is not None and nbytes > self.max_bytes:
            if self._on_too_large is not None:
                self._on_too_large()
            return
        self._callback(BusMessage(kind, key, {**body, "time_ns": time_ns}, time_ns, nbytes))
        self.n_received += 1

    def close(self) -> None:
        """Unsubscribe (idempotent)."""
        self.bus._remove(self)

    def __enter__(self) -> MemorySubscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class MemoryBus:
    """The keys of one ``unit`` inside one process (module docstring).

    ``put`` may be called from several threads (the plant's sender and a worker's outputs);
    each call delivers to the subscribers in subscription order before it returns.
    """

    def __init__(self, unit: str = "dryer1", clock: Callable[[], int] = time.time_ns) -> None:
        self.unit = unit
        self._clock = clock
        self._subs: tuple[MemorySubscription, ...] = ()
        self._lock = threading.Lock()  # subscribing and unsubscribing, not delivery
        self._keys = {kind: zenoh_key(kind, unit) for kind in KINDS}
        self.n_published = 0

    def subscribe(self, callback: Receive, kinds: Iterable[str] = KINDS, *,
                  max_bytes: int | None = None, on_too_large: Callable[[], None] | None = None,
                  sized: bool = False) -> MemorySubscription:
        """Deliver every later message of ``kinds`` to ``callback`` (on the putting thread);
        the :class:`~softsensor.bus.transport.InputSide` bounds as :class:`MemoryInput` says."""
        sub = MemorySubscription(self, callback, kinds, max_bytes=max_bytes,
                                 on_too_large=on_too_large, sized=sized)
        with self._lock:
            self._subs = (*self._subs, sub)
        return sub

    def _remove(self, sub: MemorySubscription) -> None:
        with self._lock:
            self._subs = tuple(s for s in self._subs if s is not sub)

    def put(self, kind: str, body: dict[str, Any], time_ns: int | None = None) -> None:
        """Send ``body`` on the key of ``kind`` with ``time_ns`` [ns since the epoch; the
        clock when omitted] to every subscriber of ``kind``, in order, before returning."""
        key = self._keys[kind]
        t = self._clock() if time_ns is None else int(time_ns)
        for sub in self._subs:  # a snapshot: a subscription made meanwhile starts next put
            if kind in sub.kinds:
                sub.deliver(kind, key, body, t)
        self.n_published += 1


class MemoryInput:
    """A worker's input side on a :class:`MemoryBus`: its ``scan`` and ``lab`` messages
    (:class:`~softsensor.bus.transport.InputSide`)."""

    def __init__(self, bus: MemoryBus) -> None:
        self.bus = bus
        self._sub: MemorySubscription | None = None

    def open(self, receive: Receive, *, max_bytes: int | None = None,
             on_too_large: Callable[[], None] | None = None, sized: bool = False) -> None:
        if self._sub is not None:
            raise RuntimeError("this input side is open already")
        self._sub = self.bus.subscribe(receive, INPUT_KINDS, max_bytes=max_bytes,
                                       on_too_large=on_too_large, sized=sized)

    @property
    def n_received(self) -> int:
        return 0 if self._sub is None else self._sub.n_received

    @property
    def n_errors(self) -> int:
        return 0 if self._sub is None else self._sub.n_errors

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()


class MemoryOutput:
    """A worker's output side on a :class:`MemoryBus`
    (:class:`~softsensor.bus.transport.OutputSide`): each ``put`` reaches the bus's
    subscribers before it returns. After :meth:`close` a ``put`` raises RuntimeError."""

    def __init__(self, bus: MemoryBus) -> None:
        self.bus = bus
        self._closed = False

    def put(self, kind: str, body: dict[str, Any], time_ns: int | None = None) -> None:
        if self._closed:
            raise RuntimeError(f"{kind} put on a closed output side")
        self.bus.put(kind, body, time_ns)

    def close(self) -> None:
        self._closed = True


__all__ = ["MemoryBus", "MemoryInput", "MemoryOutput", "MemorySubscription"]
