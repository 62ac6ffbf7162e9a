"""Structured logs for the daemon: one line per event, ``key=value`` or JSON.

:func:`event` logs an event name with fields (``event(log, "tick", window_end_ns=..., status=
"ok")``); :class:`KeyValueFormatter` renders every record as ``ts=... level=info logger=...
event=tick window_end_ns=... status=ok`` and :class:`JsonFormatter` as one JSON object per
line. Records from other modules (plain messages) appear with their message as the event.
:func:`configure_logging` installs one of them on the root logger's handlers, with
:class:`LibraryLines`: a library's line (pymodbus, asyncio, asyncua, zenoh) is cut to its first
line without traceback or frame dump, and a repeated one goes out at most every 30 s with the
count held back, as the project's own repeated lines do (:mod:`softsensor.log_throttle`).
Before, 500 Modbus requests to unit 0 logged 500 pymodbus tracebacks with a dump of the
daemon's own PLC frames (624 kB), and a descriptor shortage made asyncio log
``socket.accept() out of system resource`` 1,977,599 times in four minutes.
"""

from __future__ import annotations

import json
import logging
import re
import sys
from datetime import UTC, datetime
from typing import Any

from softsensor.jsonable import finite_or_none
from softsensor.log_throttle import Throttle, outside_text

_FIELDS = "softsensor_fields"


def event(logger: logging.Logger, name: str, level: int = logging.INFO, **fields: Any) -> None:
    """Log the event ``name`` with ``fields`` (rendered by the structured formatters)."""
    if logger.isEnabledFor(level):
        logger.log(level, name, extra={_FIELDS: fields})


def _ts(record: logging.LogRecord) -> str:
    t = datetime.fromtimestamp(record.created, tz=UTC)
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _fields(record: logging.LogRecord) -> dict[str, Any]:
    out: dict[str, Any] = {"ts": _ts(record), "level": record.levelname.lower(),
                           "logger": record.name, "event": record.getMessage()}
    out.update(getattr(record, _FIELDS, {}) or {})
    if record.exc_info:
        exc = record.exc_info[1]
        out["error"] = f"{type(exc).__name__}: {exc}" if exc else "error"
    return out


def _kv_value(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        v = finite_or_none(v)  # as JSON says it
        return "null" if v is None else repr(v)
    if isinstance(v, int):
        return str(v)
    text = v if isinstance(v, str) else json.dumps(v, default=str, separators=(",", ":"))
    if text and all(c.isalnum() or c in "._-:/+@" for c in text):
        return text
    return json.dumps(text)


class KeyValueFormatter(logging.Formatter):
    """``ts=... level=... logger=... event=... key=value ...`` on one line."""

    def format(self, record: logging.LogRecord) -> str:
        return " ".join(f"{k}={_kv_value(v)}" for k, v in _fields(record).items())


class JsonFormatter(logging.Formatter):
    """One JSON object per line."""

    def format(self, record: logging.LogRecord) -> str:
        return json.dumps(_fields(record), default=str, separators=(",", ":"))


#: Loggers whose records are the project's own (throttled where they are logged).
OWN_LOGGER = "softsensor"
_NUMBERS = re.compile(r"\d+")
_DECISION = "softsensor_library_line"


class LibraryLines(logging.Filter):
    """Every other logger's record on one line and throttled (module docstring): ``every_s``
    between two lines of one kind (the logger, the level and the first line's words, numbers
    left out, so "device id 0" and "device id 255" are one kind)."""

    def __init__(self, every_s: float = 30.0, clock=None) -> None:
        super().__init__()
        self.throttle = Throttle(every_s) if clock is None else Throttle(every_s, clock)

    def filter(self, record: logging.LogRecord) -> bool:
        if record.name == OWN_LOGGER or record.name.startswith(OWN_LOGGER + "."):
            return True
        decided = getattr(record, _DECISION, None)
        if decided is not None and decided[0] is self:  # on a second handler: same answer
            return decided[1]
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a library's malformed format: keep its template
            text = str(record.msg)
        first = text.split("\n", 1)[0]
        kind = f"{record.name} {record.levelno} {_NUMBERS.sub('#', first)[:80]}"
        held = self.throttle.ready(kind)
        keep = held is not None
        if keep:
            line = outside_text(first)
            if held:
                line += (f" ({held} more like it in the last {self.throttle.every_s:.0f} s "
                         f"not logged)")
            record.msg, record.args = line, None
            record.exc_info = record.exc_text = record.stack_info = None
        setattr(record, _DECISION, (self, keep))
        return keep


def configure_logging(fmt: str = "kv", level: int | None = None) -> None:
    """Use the ``kv`` or ``json`` formatter on every root handler (one on stderr if none),
    each behind one :class:`LibraryLines`."""
    formatter: logging.Formatter = JsonFormatter() if fmt == "json" else KeyValueFormatter()
    root = logging.getLogger()
    if not root.handlers:
        root.addHandler(logging.StreamHandler(sys.stderr))
    library = LibraryLines()
    for handler in root.handlers:
        handler.setFormatter(formatter)
        for old in [f for f in handler.filters if isinstance(f, LibraryLines)]:
            handler.removeFilter(old)
        handler.addFilter(library)
    if level is not None:
        root.setLevel(level)


__all__ = ["OWN_LOGGER", "JsonFormatter", "KeyValueFormatter", "LibraryLines", "configure_logging",
           "event"]
