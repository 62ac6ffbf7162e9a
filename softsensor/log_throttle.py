"""Repeated log lines, rate-limited with a count: what a flood or a broken device may cost.

A hostile peer or a broken device can make the same warning happen thousands of times a
second (20,000 non-JSON scans made 37,912 lines; a read-only checkpoint folder 1,799 lines in
two minutes). A :class:`Throttle` lets the first line of a kind out at once and then at most
one every ``every_s`` seconds, and says how many it held back in between, so the log keeps
the news (it started, it goes on, how much) without the flood. Text from outside (a key, a
sample id, an exception's message) goes through :func:`softsensor.errors.one_line` with a
bound (:data:`TEXT_CHARS`) before it is logged.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from softsensor.errors import one_line

#: Longest text from outside (keys, ids, messages) put into a log line [characters].
TEXT_CHARS = 200
#: Kinds a throttle tells apart; beyond, they share one line (keys come from the program,
#: but this bounds the memory if one ever came from outside).
MAX_KINDS = 64


def outside_text(text: object) -> str:
    """``text`` from outside as one printable line of at most :data:`TEXT_CHARS`."""
    return one_line(str(text), TEXT_CHARS)


class Throttle:
    """At most one line per kind every ``every_s`` seconds (module docstring)."""

    def __init__(self, every_s: float = 30.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.every_s = float(every_s)
        self._clock = clock
        self._lock = threading.Lock()  # called from Zenoh's and the estimator's threads
        self._last: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def ready(self, kind: str = "") -> int | None:
        """None when a line of ``kind`` must be held back now (it is counted), else how many
        were held back since the last one that went out."""
        now = self._clock()
        with self._lock:
            if kind not in self._last and len(self._last) >= MAX_KINDS:
                kind = "(other)"
            last = self._last.get(kind)
            if last is not None and now - last < self.every_s:
                self._held[kind] = self._held.get(kind, 0) + 1
                return None
            self._last[kind] = now
            return self._held.pop(kind, 0)

    def log(self, logger: logging.Logger, kind: str, level: int, msg: str, *args: Any,
            exc_info: bool = False) -> None:
        """``logger.log(level, msg, *args)`` when :meth:`ready`, with the count held back."""
        held = self.ready(kind)
        if held is None or not logger.isEnabledFor(level):
            return
        if held:
            msg += f" ({held} more like it in the last {self.every_s:.0f} s not logged)"
        logger.log(level, msg, *args, exc_info=exc_info)


__all__ = ["MAX_KINDS", "TEXT_CHARS", "Throttle", "outside_text"]
