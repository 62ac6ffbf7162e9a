"""Structured logs for the daemon: one line per event, ``key=value`` or JSON.

:func:`event` logs an event name with fields (``event(log, "tick", window_end_ns=..., status=
"ok")``); :class:`KeyValueFormatter` renders every record as ``ts=... level=info logger=...
event=tick window_end_ns=... status=ok`` and :class:`JsonFormatter` as one JSON object per
line. Records from other modules (plain messages) appear with their message as the event.
:func:`configure_logging` installs one of them on the root logger's handlers.
"""

from __future__ import annotations

import json
import logging
import sys
from datetime import UTC, datetime
from typing import Any

from softsensor.jsonable import finite_or_none

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


def configure_logging(fmt: str = "kv", level: int | None = None) -> None:
    """Use the ``kv`` or ``json`` formatter on every root handler (one on stderr if none)."""
    formatter: logging.Formatter = JsonFormatter() if fmt == "json" else KeyValueFormatter()
    root = logging.getLogger()
    if not root.handlers:
        root.addHandler(logging.StreamHandler(sys.stderr))
    for handler in root.handlers:
        handler.setFormatter(formatter)
    if level is not None:
        root.setLevel(level)


__all__ = ["JsonFormatter", "KeyValueFormatter", "configure_logging", "event"]
