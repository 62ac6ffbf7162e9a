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

A full disk (or less free than ``reserve_bytes``) pauses recording instead of failing every
message: the open files are finished while there is room (else cut after their last complete
chunk, readable with ``allow_truncated``; a file that would hold nothing is removed, so no
empty day file is left), one error line says so, :attr:`Recorder.failure` holds the reason
(``"disk full"``) for health, the messages that come meanwhile wait in memory (at most
``backlog`` of them; older ones are dropped and counted in :attr:`Recorder.n_lost`), and
recording resumes, backlog first, at the first retry (every ``retry_s``, doubling to
:data:`MAX_RETRY_S`) that finds room again.

What feeds a recorder from the Zenoh bus (:class:`~softsensor.service.bus_recorder.
BusRecorder`) lives with the service, which wires the adapters together: this module knows no
bus.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from datetime import date, timedelta
from pathlib import Path
from typing import Any

from softsensor.errors import IngestError, SoftsensorError
from softsensor.log_throttle import Throttle
from softsensor.recording.day_writer import DayWriter

log = logging.getLogger(__name__)

NS_PER_DAY = 86_400 * 10**9
#: Default uncompressed chunk size of recorded files [bytes].
RECORDER_CHUNK_SIZE = 16 * 1024
#: Longest wait between attempts to resume recording after a failure [s, wall].
MAX_RETRY_S = 60.0
#: Free space is looked at no more often than this while recording [s, wall].
SPACE_CHECK_S = 1.0


def free_bytes(folder: Path) -> int:
    """Bytes an unprivileged writer may still use in ``folder``'s file system."""
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


def _reason(exc: BaseException) -> str:
    """What a failed write means, in the words a health line uses."""
    os_error = exc if isinstance(exc, OSError) else exc.__cause__
    if isinstance(os_error, OSError) and os_error.errno in (errno.ENOSPC, errno.EDQUOT):
        return "disk full"
    if isinstance(os_error, OSError):
        return os_error.strerror or str(os_error)
    return str(exc)


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
        Monotonic clock [s] for the flush interval and the retries.
    reserve_bytes : int
        Free space below which recording pauses as for a full disk (room for the files'
        summaries and for the rest of the system) [bytes].
    retry_s : float
        First wait before recording is tried again after a failure [s, wall].
    backlog : int
        Messages kept in memory while recording is paused.
    """

    def __init__(self, directory: str | os.PathLike[str], unit: str = "dryer1", *,
                 chunk_size: int = RECORDER_CHUNK_SIZE, flush_interval_s: float = 30.0,
                 grace_s: float = 600.0, clock: Callable[[], float] = time.monotonic,
                 reserve_bytes: int = 0, retry_s: float = 5.0, backlog: int = 10_000) -> None:
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
        self.reserve_bytes = int(reserve_bytes)
        self.first_retry_s = float(retry_s)
        self.failure: str | None = None  #: why recording is paused (None: recording)
        self.n_failures = 0  #: times recording was paused
        self.n_lost = 0  #: messages dropped while paused (the backlog was full)
        self._backlog: deque[tuple[str, int, dict[str, Any], int]] = deque(maxlen=backlog)
        self._retry_s = self.first_retry_s
        self._retry_at = 0.0
        self._space_checked = -math.inf
        self._throttle = Throttle()

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
            self._throttle.log(log, "late", logging.WARNING, "late message for %s recorded in %s",
                               day, self._writers[newest].path)
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
        that of ``file_time_ns`` (the recorder's clock, live) or else of ``log_time_ns``.
        While recording is paused (module docstring) the message waits in memory."""
        t = int(log_time_ns)
        item = (topic, t, body, t if file_time_ns is None else int(file_time_ns))
        with self._lock:
            if self._closed:
                raise ValueError(f"{self.directory}: recorder is closed")
            if self.failure is not None and not self._resume():
                self._keep(item)
                return
            try:
                self._check_space()
                self._write(item)
            except (OSError, IngestError) as exc:
                self._pause(exc, item)

    def _write(self, item: tuple[str, int, dict[str, Any], int]) -> None:
        topic, t, body, ft = item
        self._newest_ns = ft if self._newest_ns is None else max(self._newest_ns, ft)
        day, writer = self._writer_for(utc_date(ft))
        writer.write(topic, t, body)
        self.n_written += 1
        self._dirty_since.setdefault(day, self._clock())
        if len(self._writers) > 1:
            self._close_old_days()
        self._flush_due()

    def _check_space(self, need: int | None = None) -> None:
        """Raise ENOSPC when less than ``need`` (the reserve) is free (looked at once a
        second at most, unless ``need`` is given)."""
        if not self.reserve_bytes:
            return
        now = self._clock()
        if need is None and now - self._space_checked < SPACE_CHECK_S:
            return
        self._space_checked = now
        if free_bytes(self.directory) < (need or self.reserve_bytes):
            raise OSError(errno.ENOSPC, f"less than {need or self.reserve_bytes} bytes free")

    def _keep(self, item: tuple[str, int, dict[str, Any], int]) -> None:
        if len(self._backlog) == self._backlog.maxlen:
            self.n_lost += 1  # the oldest goes
        self._backlog.append(item)

    def _pause(self, exc: BaseException,
               failed: tuple[str, int, dict[str, Any], int] | None = None) -> None:
        """Stop writing after ``exc``: finish (or cut) the open files, keep what did not reach
        them (``failed``, the message being written, and the cut files' open chunks) at the
        head of the backlog, retry later."""
        writers, self._writers = self._writers, {}
        self._dirty_since.clear()
        back: list[tuple[str, int, dict[str, Any], int]] = []
        for day, writer in sorted(writers.items()):
            try:
                writer.close()
            except OSError:
                writer.abandon()
                # (their day files are the recorder's clock's; kept as the day of the file)
                ft = _midnight_ns(day)
                back += [(topic, t, body, max(ft, min(t, ft + NS_PER_DAY - 1)))
                         for topic, t, body in writer.unsaved]
        if failed is not None and not any(b[2] is failed[2] for b in back):
            back.append(failed)
        for item in reversed(back):
            if len(self._backlog) == self._backlog.maxlen:
                self.n_lost += 1  # the newest goes
            self._backlog.appendleft(item)
        self.paths = [p for p in self.paths if p.exists()]
        first = self.failure is None
        self.failure = _reason(exc)
        self._retry_at = self._clock() + self._retry_s
        self._retry_s = min(2.0 * self._retry_s, MAX_RETRY_S)
        if first:
            self.n_failures += 1
            log.error("recording paused: %s: %s (%s); estimation goes on, up to %d messages "
                      "wait in memory, retrying every %.0f to %.0f s", self.directory,
                      self.failure, exc, self._backlog.maxlen, self.first_retry_s, MAX_RETRY_S)

    def _resume(self, force: bool = False) -> bool:
        """Try to record again (at the retry time, or now with ``force``); True if writing."""
        if not force and self._clock() < self._retry_at:
            return False
        item = None
        try:
            self._check_space(need=2 * self.reserve_bytes)  # resume with room to spare
            while self._backlog:
                item = self._backlog.popleft()
                self._write(item)
                item = None
        except (OSError, IngestError) as exc:
            self._pause(exc, item)  # (item goes back first, once)
            return False
        log.warning("recording resumed in %s after %s; %d messages lost while paused",
                    self.directory, self.failure, self.n_lost)
        self.failure = None
        self._retry_s = self.first_retry_s
        return True

    def _flush_due(self) -> None:
        now = self._clock()
        for day, since in list(self._dirty_since.items()):
            if now - since >= self.flush_interval_s:
                self._writers[day].flush()
                del self._dirty_since[day]

    def tick(self) -> None:
        """Write out chunks older than ``flush_interval_s``, or try to resume a paused
        recording (call it periodically when idle)."""
        with self._lock:
            if self._closed:
                return
            if self.failure is not None:
                self._resume()
                return
            try:
                self._flush_due()
            except OSError as exc:
                self._pause(exc)

    def flush(self) -> None:
        """Write out every open chunk now."""
        with self._lock:
            if self._closed:
                return
            try:
                for writer in self._writers.values():
                    writer.flush()
            except OSError as exc:
                self._pause(exc)
            self._dirty_since.clear()

    def close(self) -> None:
        """Finish and close every open file (idempotent); a paused recording writes what
        waits in memory if there is room now."""
        with self._lock:
            if self._closed:
                return
            if self.failure is not None and self._backlog:
                self._resume(force=True)
            self._closed = True
            writers, self._writers = self._writers, {}
            self._dirty_since.clear()
            if self._backlog:
                self.n_lost += len(self._backlog)
                log.error("recording: %d messages waiting in memory lost at shutdown (%s)",
                          len(self._backlog), self.failure)
                self._backlog.clear()
        errors = []
        for writer in writers.values():
            try:
                writer.close()
            except OSError as exc:  # keep closing the others; the file ends after a chunk
                writer.abandon()
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
