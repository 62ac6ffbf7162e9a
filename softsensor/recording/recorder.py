"""Record everything into MCAP files rotated daily by UTC date.

:class:`Recorder` takes ``(topic, log_time_ns, body)`` from any thread and writes it to
``<dir>/<unit>-YYYYMMDD.mcap`` for the UTC date of ``log_time_ns`` (``-01``, ``-02``, ... are
appended when a file of that name exists, so a restart never overwrites a day). Chunks are
small, zstd compressed and handed to the OS as soon as they are full or ``flush_interval_s``
after the first message of the chunk, so a recorder killed outright loses at most that much;
the file then reads with ``read_day(..., allow_truncated=True)``. :meth:`Recorder.close`
finishes every file (summary, footer), after which it reads normally.

A day's file is kept open until the newest message is ``grace_s`` past its midnight, so a
message logged a little late still lands in its own day; later stragglers go into the newest
file (readers sort by log time).

What feeds a recorder from the Zenoh bus (:class:`~softsensor.service.bus_recorder.
BusRecorder`) lives with the service, which wires the adapters together: this module knows no
bus.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from datetime import date, timedelta
from pathlib import Path
from typing import Any

from softsensor.errors import SoftsensorError
from softsensor.recording.mcap_day import DayWriter

log = logging.getLogger(__name__)

NS_PER_DAY = 86_400 * 10**9
#: Default uncompressed chunk size of recorded files [bytes].
RECORDER_CHUNK_SIZE = 16 * 1024


def utc_date(time_ns: int) -> date:
    """UTC calendar date of a time in ns since the epoch."""
    return date(1970, 1, 1) + timedelta(days=time_ns // NS_PER_DAY)


def day_file_name(unit: str, day: date, n: int = 0) -> str:
    """``<unit>-YYYYMMDD.mcap``, or ``<unit>-YYYYMMDD-NN.mcap`` for the n-th file of a day."""
    stem = f"{unit}-{day:%Y%m%d}"
    return f"{stem}.mcap" if n == 0 else f"{stem}-{n:02d}.mcap"


def _midnight_ns(day: date) -> int:
    return (day - date(1970, 1, 1)).days * NS_PER_DAY


class Recorder:
    """Thread-safe MCAP recorder with daily rotation by UTC date.

    Parameters
    ----------
    directory : str or Path
        Folder of the day files (created if missing).
    unit : str
        Unit name, the prefix of the file names.
    chunk_size : int
        Uncompressed chunk size [bytes]; a full chunk is written at once.
    flush_interval_s : float
        Longest time a message waits in an open chunk before it is written [s, wall clock].
        Checked on every write and by :meth:`tick`.
    grace_s : float
        How long past midnight (in log time) the previous day's file stays open [s].
    clock : callable
        Monotonic clock [s] for the flush interval.
    """

    def __init__(self, directory: str | os.PathLike[str], unit: str = "dryer1", *,
                 chunk_size: int = RECORDER_CHUNK_SIZE, flush_interval_s: float = 30.0,
                 grace_s: float = 600.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.directory = Path(directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SoftsensorError(f"{self.directory}: cannot create recording folder: "
                                  f"{exc.strerror}") from exc
        self.unit = unit
        self.chunk_size = chunk_size
        self.flush_interval_s = flush_interval_s
        self.grace_ns = int(grace_s * 1e9)
        self._clock = clock
        self._lock = threading.Lock()
        self._writers: dict[date, DayWriter] = {}
        self._dirty_since: dict[date, float] = {}
        self._newest_ns: int | None = None
        self._closed = False
        self.paths: list[Path] = []
        self.n_written = 0

    # -- files

    def _new_path(self, day: date) -> Path:
        n = 0
        while (self.directory / day_file_name(self.unit, day, n)).exists():
            n += 1
        return self.directory / day_file_name(self.unit, day, n)

    def _writer_for(self, day: date) -> tuple[date, DayWriter]:
        writer = self._writers.get(day)
        if writer is not None:
            return day, writer
        newest = max(self._writers, default=None)
        if newest is not None and day < newest:
            # a straggler for a day already closed: keep it in the newest file
            log.warning("late message for %s recorded in %s", day, self._writers[newest].path)
            return newest, self._writers[newest]
        path = self._new_path(day)
        writer = DayWriter(path, chunk_size=self.chunk_size)
        log.info("recording to %s", path)
        self._writers[day] = writer
        self.paths.append(path)
        return day, writer

    def _close_old_days(self) -> None:
        assert self._newest_ns is not None
        for day in sorted(self._writers):
            if self._newest_ns >= _midnight_ns(day) + NS_PER_DAY + self.grace_ns:
                if day == max(self._writers):
                    break  # never close the newest file: stragglers need a home
                self._writers.pop(day).close()
                self._dirty_since.pop(day, None)

    # -- public API

    def write(self, topic: str, log_time_ns: int, body: dict[str, Any], *,
              file_time_ns: int | None = None) -> None:
        """Record one message stamped ``log_time_ns`` [ns since epoch, UTC]; the day file is
        that of ``file_time_ns`` (the recorder's clock, live) or else of ``log_time_ns``."""
        t = int(log_time_ns)
        ft = t if file_time_ns is None else int(file_time_ns)
        with self._lock:
            if self._closed:
                raise ValueError(f"{self.directory}: recorder is closed")
            self._newest_ns = ft if self._newest_ns is None else max(self._newest_ns, ft)
            day, writer = self._writer_for(utc_date(ft))
            writer.write(topic, t, body)
            self.n_written += 1
            self._dirty_since.setdefault(day, self._clock())
            if len(self._writers) > 1:
                self._close_old_days()
            self._flush_due()

    def _flush_due(self) -> None:
        now = self._clock()
        for day, since in list(self._dirty_since.items()):
            if now - since >= self.flush_interval_s:
                self._writers[day].flush()
                del self._dirty_since[day]

    def tick(self) -> None:
        """Write out chunks older than ``flush_interval_s`` (call it periodically when idle)."""
        with self._lock:
            if not self._closed:
                self._flush_due()

    def flush(self) -> None:
        """Write out every open chunk now."""
        with self._lock:
            if self._closed:
                return
            for writer in self._writers.values():
                writer.flush()
            self._dirty_since.clear()

    def close(self) -> None:
        """Finish and close every open file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            writers, self._writers = self._writers, {}
            self._dirty_since.clear()
        errors = []
        for writer in writers.values():
            try:
                writer.close()
            except OSError as exc:  # keep closing the others
                errors.append(f"{writer.path}: {exc}")
        if errors:
            raise SoftsensorError("could not close " + "; ".join(errors))

    @property
    def open_paths(self) -> list[Path]:
        """Files currently open for writing."""
        with self._lock:
            return [w.path for _, w in sorted(self._writers.items())]

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "RECORDER_CHUNK_SIZE",
    "Recorder",
    "day_file_name",
    "utc_date",
]
