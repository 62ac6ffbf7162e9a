"""What a bus carries and the two sides a worker sees of it, whatever the bus is.

A bus message is one of the CONTRACT key kinds (section 3: ``scan`` and ``lab`` in from the
plant, ``estimate`` and ``health`` out of the soft sensor) with a JSON body and its event time
``time_ns`` [ns since the epoch, UTC], which the payload carries as a body field too.

The estimator's worker (:class:`~softsensor.service.bus_worker.BusWorker`) talks to a bus
through two small interfaces, as httpx's client talks to its transport:

* an :class:`InputSide` hands it the decoded input messages, one source's in the order they
  were sent, and refuses those over a byte bound before decoding them;
* an :class:`OutputSide` sends each of its output messages.

Two pairs implement them: Zenoh (:class:`~softsensor.bus.zenoh_bus.ZenohInput` and
:class:`~softsensor.bus.zenoh_bus.Publisher`: the daemon, and ``replay --via-zenoh``) and
in-process memory (:class:`~softsensor.bus.memory.MemoryInput` and
:class:`~softsensor.bus.memory.MemoryOutput` on a :class:`~softsensor.bus.memory.MemoryBus`:
``replay``, and tests, with no sockets, no threads and no waits).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

from softsensor.messages import encode_body
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN

#: Key kinds (CONTRACT section 3) and the MCAP topic each one is recorded under.
KIND_TOPIC: dict[str, str] = {
    "scan": TOPIC_SCAN,
    "lab": TOPIC_LAB,
    "estimate": TOPIC_ESTIMATE,
    "health": TOPIC_HEALTH,
}
TOPIC_KIND: dict[str, str] = {topic: kind for kind, topic in KIND_TOPIC.items()}
KINDS: tuple[str, ...] = tuple(KIND_TOPIC)
#: What the plant sends the estimator, and what the estimator sends back.
INPUT_KINDS: tuple[str, ...] = ("scan", "lab")
OUTPUT_KINDS: tuple[str, ...] = ("estimate", "health")


class BusMessage(NamedTuple):
    """A decoded bus message. ``time_ns`` is the body's event time [ns] (None if absent);
    ``nbytes`` the size of its payload (what a queue of messages is bounded by)."""

    kind: str
    key: str
    body: dict[str, Any]
    time_ns: int | None
    nbytes: int = 0

    @property
    def topic(self) -> str:
        """MCAP topic this message is recorded under."""
        return KIND_TOPIC[self.kind]


def encode_payload(body: dict[str, Any], time_ns: int) -> bytes:
    """JSON payload of a bus message: ``body`` plus ``time_ns`` [ns since epoch]; NaN -> null."""
    return encode_body({**body, "time_ns": int(time_ns)})


#: What an input side hands each admitted-for-decoding message to.
Receive = Callable[[BusMessage], None]


class InputSide(Protocol):
    """Where a worker's input messages come from.

    :meth:`open` starts delivery: every later ``scan`` and ``lab`` message of the unit goes to
    ``receive`` as a :class:`BusMessage`, one sender's in the order it sent them (``receive``
    must not block: it may run on the bus's own thread). A payload longer than ``max_bytes``
    is not decoded: ``on_too_large()`` is called instead. ``sized`` asks for each message's
    ``nbytes`` (its payload's length) where it costs something to know. A malformed message
    is counted in ``n_errors`` and logged, never raised; ``n_received`` counts the messages
    handed to ``receive``. :meth:`close` stops delivery (idempotent).
    """

    @property
    def n_received(self) -> int: ...

    @property
    def n_errors(self) -> int: ...

    def open(self, receive: Receive, *, max_bytes: int | None = None,
             on_too_large: Callable[[], None] | None = None, sized: bool = False) -> None: ...

    def close(self) -> None: ...


class OutputSide(Protocol):
    """Where a worker's output messages go: ``put(kind, body, time_ns)`` sends ``body`` on
    the unit's key of ``kind`` with ``time_ns`` [ns since the epoch]; :meth:`close` releases
    what the side holds on the bus (idempotent)."""

    def put(self, kind: str, body: dict[str, Any], time_ns: int | None = None) -> None: ...

    def close(self) -> None: ...


__all__ = ["INPUT_KINDS", "KINDS", "KIND_TOPIC", "OUTPUT_KINDS", "TOPIC_KIND", "BusMessage",
           "InputSide", "OutputSide", "Receive", "encode_payload"]
