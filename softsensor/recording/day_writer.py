"""Writing recorded days: MCAP files of JSON messages with JSON Schemas (CONTRACT section 2).

:class:`DayWriter` registers one JSON Schema (encoding ``jsonschema``, :data:`SCHEMAS`) and one
channel (message encoding ``json``) per topic on first use, compresses chunks with zstd and
keeps chunks small, so a writer that dies loses at most its open chunk. A float NaN in a body
is written as ``null``. Reading them back: :mod:`softsensor.recording.mcap_day`.

Times are nanoseconds since the Unix epoch, UTC, everywhere.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from softsensor.errors import IngestError
from softsensor.messages import encode_body
from softsensor.signals import (
    HEALTH_STATES,
    SCAN_SIGNALS,
    TOPIC_ESTIMATE,
    TOPIC_HEALTH,
    TOPIC_LAB,
    TOPIC_SCAN,
)

#: Default uncompressed chunk size [bytes]: about 100 scans, so a crash loses minutes, not hours.
DEFAULT_CHUNK_SIZE = 32 * 1024

_NUM_OR_NULL = {"type": ["number", "null"]}

SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_SCAN: (
        "softsensor.PlantScan",
        {
            "title": "PLC scan (SI units; null = signal could not be read)",
            "type": "object",
            "properties": {name: dict(_NUM_OR_NULL, description=unit)
                           for name, unit in SCAN_SIGNALS.items()},
            "additionalProperties": True,
        },
    ),
    TOPIC_LAB: (
        "softsensor.LabResult",
        {
            "title": "Laboratory moisture result, logged when it became available",
            "type": "object",
            "properties": {
                "sample_time_ns": {"type": "integer", "description": "ns since epoch, UTC"},
                "moisture_out": {"type": "number", "description": "kg/kg dry basis"},
                "sample_id": {"type": "string"},
            },
            "required": ["sample_time_ns", "moisture_out", "sample_id"],
            "additionalProperties": True,
        },
    ),
    TOPIC_ESTIMATE: (
        "softsensor.Estimate",
        {
            "title": "Soft-sensor estimate (SI units)",
            "type": "object",
            "properties": {
                "moisture_out": _NUM_OR_NULL,
                "moisture_out_std": _NUM_OR_NULL,
                "moisture_in": _NUM_OR_NULL,
                "moisture_in_std": _NUM_OR_NULL,
                "T_dryer_out_model": _NUM_OR_NULL,
                "T_cyclone_out_model": _NUM_OR_NULL,
                "lab_updated": {"type": "boolean"},
            },
            "required": [
                "moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std",
                "T_dryer_out_model", "T_cyclone_out_model", "lab_updated",
            ],
            "additionalProperties": True,
        },
    ),
    TOPIC_HEALTH: (
        "softsensor.Health",
        {
            "title": "Soft-sensor health",
            "type": "object",
            "properties": {
                "status": {"type": "string", "enum": list(HEALTH_STATES)},
                "detail": {"type": "string"},
            },
            "required": ["status", "detail"],
            "additionalProperties": True,
        },
    ),
}

_PERMISSIVE_SCHEMA = {"type": "object", "additionalProperties": True}


class _UnbufferedFile:
    """A write-only file whose writes reach the OS at once (the MCAP writer writes whole chunks).

    ``mcap.Writer`` keeps any stream that is not an ``io.RawIOBase`` as it is (it would wrap a
    raw file in a buffer), so every finished chunk is in the OS and survives a SIGKILL. The
    writer hands over one whole record (a chunk, its indexes) per call; a call that fails (a
    full disk) is cut off again, so the file always ends after a complete record.
    """

    def __init__(self, path: Path) -> None:
        self._f = open(path, "wb", buffering=0)  # noqa: SIM115 - closed in close()

    def write(self, data: bytes) -> int:
        start = self._f.tell()
        view = memoryview(data)
        try:
            while view:
                n = self._f.write(view)
                view = view[n:]
        except OSError:
            try:  # no half record: what was written before this call stays readable
                self._f.truncate(start)
                self._f.seek(start)
            except OSError:
                pass
            raise
        return len(data)

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        pass

    def fsync(self) -> None:
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()

    @property
    def closed(self) -> bool:
        return self._f.closed


class DayWriter:
    """Writes one recorded period into an MCAP file.

    Parameters
    ----------
    path : str or Path
        File to create (overwritten if it exists).
    chunk_size : int
        Uncompressed size at which a chunk is closed and written [bytes]. A writer that dies
        loses at most the chunk it has open.

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | os.PathLike[str], *,
                 chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
        self.path = Path(path)
        try:
            self._file = _UnbufferedFile(self.path)
        except OSError as exc:
            raise IngestError(f"{self.path}: cannot create MCAP file: {exc.strerror}") from exc
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD)
        try:
            self._writer.start(profile="", library="softsensor")
        except OSError as exc:  # a full disk: no empty file left behind
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise IngestError(f"{self.path}: cannot create MCAP file: {exc.strerror}") from exc
        self._header_end = self._file.tell()
        self._channels: dict[str, int] = {}
        self._closed = False
        self.n_messages = 0
        #: messages written since the last chunk reached the file (lost if it never does:
        #: a recorder that has to cut the file keeps them for the next one)
        self.unsaved: list[tuple[str, int, dict[str, Any]]] = []

    def _channel(self, topic: str) -> int:
        channel_id = self._channels.get(topic)
        if channel_id is None:
            default = (f"softsensor.{topic.strip('/')}", _PERMISSIVE_SCHEMA)
            name, schema = SCHEMAS.get(topic, default)
            schema_id = self._writer.register_schema(
                name=name, encoding="jsonschema", data=json.dumps(schema).encode())
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id)
            self._channels[topic] = channel_id
        return channel_id

    def write(self, topic: str, log_time_ns: int, body: dict[str, Any]) -> None:
        """Append one message; ``log_time_ns`` in ns since the epoch, UTC."""
        if self._closed:
            raise ValueError(f"{self.path}: write after close")
        t = int(log_time_ns)
        self.unsaved.append((topic, t, body))
        size = self._file.tell()
        self._writer.add_message(self._channel(topic), log_time=t, data=encode_body(body),
                                 publish_time=t)
        if self._file.tell() != size:  # the chunk, this message last, is in the file
            self.unsaved.clear()
        self.n_messages += 1

    def flush(self) -> None:
        """Close the open chunk and hand it to the OS (costs compression ratio if done often)."""
        if not self._closed:
            self._writer.flush()
            self.unsaved.clear()

    def close(self) -> None:
        """Finish the file (summary, footer) and close it. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
            self.unsaved.clear()
        finally:
            self._file.close()

    def abandon(self) -> bool:
        """Close without finishing (the disk has no room for the summary): the file ends after
        its last complete chunk and reads with ``allow_truncated``; one that holds no chunk is
        removed. True when the file was kept."""
        self._closed = True
        self._file.close()  # (again, after a close() whose summary did not fit)
        try:
            size = self.path.stat().st_size
        except FileNotFoundError:
            return False
        if size <= self._header_end:
            self.path.unlink(missing_ok=True)
            return False
        return True

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> DayWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["DEFAULT_CHUNK_SIZE", "SCHEMAS", "DayWriter"]
