"""Replay a recorded day onto the bus at a chosen pace (reads :mod:`softsensor.recording`,
feeds :mod:`softsensor.bus`: a bridge, so it sits with the service that wires them).

The MCAP topics map to Zenoh key kinds (``/plant/scan`` -> ``plant/<unit>/scan``,
``/plant/lab`` -> ``plant/<unit>/lab``, and the ``/softsensor/...`` topics likewise); topics
without a key (``/truth/...``) are never published. Messages go out in log-time order with
``time_ns`` = their log time. The pace is a speed-up factor over real time (``1.0`` = real
time, ``60`` = one hour per minute) or ``"max"`` (as fast as the sink takes them).

:func:`replay_day` is bounded (by the day, ``end`` and ``max_messages``) and stoppable (a
:class:`threading.Event`; from asyncio run it in ``asyncio.to_thread`` and set the event).
It publishes through any ``sink(kind, body, time_ns)``, e.g. :meth:`Publisher.put
<softsensor.bus.zenoh_bus.Publisher.put>` or :meth:`MemoryBus.put
<softsensor.bus.memory.MemoryBus.put>`, so tests need no network.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from softsensor.bus.transport import TOPIC_KIND
from softsensor.errors import ConfigError
from softsensor.recording.mcap_day import iter_messages
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN

#: Topics replayed by default: what the plant side publishes.
DEFAULT_TOPICS: tuple[str, ...] = (TOPIC_SCAN, TOPIC_LAB)

Sink = Callable[[str, dict[str, Any], int], None]
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def _in_range(ns: int, name: str) -> int:
    """``ns`` when it is a time between 1970 and 2262 (what an int64 of ns holds)."""
    if not 0 <= ns < 2**63:
        raise ConfigError(f"{name}: {ns} ns is not a time between 1970 and 2262")
    return ns


def parse_time(value: int | str | datetime | None, name: str = "time") -> int | None:
    """A time as ns since the epoch, UTC, from ns (int or digit string), ISO-8601 or datetime.

    Naive ISO times and datetimes are taken as UTC. ``None`` stays ``None``.
    """
    if value is None:
        return None
    if isinstance(value, bool):
        raise ConfigError(f"{name} must be ns since the epoch or an ISO-8601 time, got {value!r}")
    if isinstance(value, int):
        return _in_range(value, name)
    if isinstance(value, str):
        text = value.strip()
        if text.lstrip("-").isdigit():
            if len(text.lstrip("-")) > 19:  # before int(): 5000 digits must not be parsed
                raise ConfigError(f"{name}: {text[:25]}... is not a time (ns since the epoch "
                                  f"have at most 19 digits)")
            return _in_range(int(text), name)
        try:
            value = datetime.fromisoformat(text.replace("z", "Z"))
        except ValueError as exc:
            raise ConfigError(
                f"{name} must be ns since the epoch or an ISO-8601 time, got {text!r}") from exc
    if isinstance(value, datetime):
        if value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        delta = value - _EPOCH
        return _in_range((delta.days * 86_400 + delta.seconds) * 10**9
                         + delta.microseconds * 1000, name)
    raise ConfigError(f"{name} must be ns since the epoch or an ISO-8601 time, got {value!r}")


#: Paces a replay may run at: from a hundred times slower than real time (no day ends at
#: 1e-300, and its sleeps overflow) to a million times faster (beyond: use ``max``).
RATE_RANGE: tuple[float, float] = (0.01, 1e6)


def parse_rate(value: float | str) -> float | None:
    """Speed-up factor over real time (within :data:`RATE_RANGE`); ``None`` for ``"max"``
    (no pacing)."""
    if isinstance(value, str):
        if value.strip().lower() == "max":
            return None
        try:
            value = float(value)
        except ValueError as exc:
            raise ConfigError(f"rate must be a positive number or 'max', got {value!r}") from exc
    rate = float(value)
    if not math.isfinite(rate) or rate <= 0:
        raise ConfigError(f"rate must be a positive number or 'max', got {value!r}")
    lo, hi = RATE_RANGE
    if not lo <= rate <= hi:
        raise ConfigError(f"rate must be between {lo:g} and {hi:g} times real time, or 'max', "
                          f"got {value!r}")
    return rate


@dataclass
class ReplayStats:
    """What a replay did. Times in ns since the epoch; ``wall_s`` in seconds."""

    n_published: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    stopped: bool = False
    wall_s: float = 0.0


def replay_day(path: str | os.PathLike[str], sink: Sink, *, rate: float | str = 1.0,
               start: int | str | datetime | None = None,
               end: int | str | datetime | None = None,
               topics: Iterable[str] = DEFAULT_TOPICS, stop: threading.Event | None = None,
               max_messages: int | None = None, allow_truncated: bool = False,
               clock: Callable[[], float] = time.monotonic) -> ReplayStats:
    """Publish the messages of a recorded day through ``sink(kind, body, time_ns)``.

    Parameters
    ----------
    path : str or Path
        The recorded day (MCAP).
    sink : callable
        Receives the key kind (``scan``, ``lab``, ...), the body and its log time [ns].
    rate : float or "max"
        Speed-up over real time; ``"max"`` publishes without waiting.
    start, end : int, str or datetime, optional
        Log-time range ``[start, end)``: ns since the epoch or ISO-8601 (naive = UTC).
    topics : iterable of str
        MCAP topics to publish; each must have a Zenoh key (CONTRACT section 3).
    stop : threading.Event, optional
        Set it to end the replay early (also interrupts a wait between messages).
    max_messages : int, optional
        Publish at most this many messages.
    allow_truncated : bool
        Replay the intact part of a truncated file instead of failing.

    Raises :class:`ConfigError` for a bad rate, time or topic and
    :class:`~softsensor.errors.IngestError` for a bad file.
    """
    speed = parse_rate(rate)
    start_ns, end_ns = _time_range(start, end)
    selected = list(topics)
    for topic in selected:
        if topic not in TOPIC_KIND:
            raise ConfigError(f"topic {topic} has no Zenoh key and cannot be replayed")
    messages = iter_messages(path, topics=selected, allow_truncated=allow_truncated,
                             start_ns=start_ns, end_ns=end_ns)
    return replay_messages(messages, sink, rate=speed or "max", stop=stop,
                           max_messages=max_messages, clock=clock)


def replay_messages(messages: Iterable[tuple[str, int, dict[str, Any]]], sink: Sink, *,
                    rate: float | str = 1.0, stop: threading.Event | None = None,
                    max_messages: int | None = None,
                    clock: Callable[[], float] = time.monotonic) -> ReplayStats:
    """Publish ``(topic, log_time_ns, body)`` messages already read (in log-time order, each
    topic with a Zenoh key) through ``sink`` at ``rate``, as :func:`replay_day` does: for a
    caller that reads the day itself, once (:mod:`.offline_replay`)."""
    return _paced(messages, sink, parse_rate(rate), stop or threading.Event(), max_messages,
                  clock)


def _time_range(start: int | str | datetime | None, end: int | str | datetime | None
                ) -> tuple[int | None, int | None]:
    start_ns = parse_time(start, "start")
    end_ns = parse_time(end, "end")
    if start_ns is not None and end_ns is not None and end_ns <= start_ns:
        raise ConfigError(f"end ({end_ns}) must be after start ({start_ns})")
    return start_ns, end_ns


def _paced(messages: Iterable[tuple[str, int, dict[str, Any]]], sink: Sink,
           speed: float | None, stop: threading.Event, max_messages: int | None,
           clock: Callable[[], float]) -> ReplayStats:
    """Hand ``messages`` to ``sink``, each ``(log time - first log time) / speed`` after the
    first on ``clock`` (``speed`` None: at once), until they end, ``stop`` or the cap."""
    stats = ReplayStats()
    wall0 = clock()
    log0: int | None = None
    for topic, t, body in messages:
        if stop.is_set() or (max_messages is not None and stats.n_published >= max_messages):
            stats.stopped = stop.is_set()
            break
        if speed is not None:
            if log0 is None:
                log0, wall0 = t, clock()
            delay = wall0 + (t - log0) / 1e9 / speed - clock()
            if delay > 0 and stop.wait(delay):
                stats.stopped = True
                break
        sink(TOPIC_KIND[topic], body, t)
        stats.n_published += 1
        if stats.first_ns is None:
            stats.first_ns = t
        stats.last_ns = t
    stats.wall_s = clock() - wall0
    return stats

__all__ = ["DEFAULT_TOPICS", "ReplayStats", "parse_rate", "parse_time", "replay_day",
           "replay_messages"]
