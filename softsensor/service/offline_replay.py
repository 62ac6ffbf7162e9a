"""The streaming path, offline: a recorded day through the estimator into one estimates file.

``softsensor replay DAY.mcap --out EST.mcap`` (CONTRACT section 4) runs, in one thread::

    DayStream(DAY) -> replay_messages -> MemoryBus -> BusRecorder -> EST.mcap
                                  scan, lab |  ^ estimate, health
                                            v  |
                              BusWorker (EstimatorService + estimator)

The bus is in memory (:mod:`softsensor.bus.memory`): each scan or lab result is recorded and
then stepped through the service, whose estimates and health are recorded, before the next
message is read. Nothing is queued, nothing crosses a thread, nothing is waited for, so the
messages reach the service in log-time order. Estimates are a function of the day alone: the
service orders lab results and ticks by log time (see :mod:`.estimator_service`), provided
each lab result reaches it before the scans logged after it. Replaying the same day twice, or
replaying what the daemon recorded live, gives the same estimates.

``--via-zenoh`` (``via_zenoh=True``) keeps the real wire: two Zenoh sessions on 127.0.0.1
(free ports, scouting off) stand for the plant side and the daemon, the worker runs on its own
thread behind the service session's subscriber as in the daemon, and the recorder subscribes
to all four keys. At rate ``max`` the lab order cannot be left to Zenoh's threads, so after
publishing a lab result the replayer waits until the worker has received it (a few per day,
microseconds each), and at the end until everything is recorded. Both paths give the same
estimates and record the same messages (the conformance test in
``tests/service/test_offline_replay.py``).

Several days (``softsensor replay day1.mcap day2.mcap ...``) go through the same bus and the
same estimator as one stream, as the daemon lives them: the state carries across the
boundaries, and the hours between two days are a gap in the scans, which the service handles
as it does live (:mod:`.estimator_service`). The days must follow each other in time
(:func:`check_order`). ``checkpoint_in`` starts the estimator from a checkpoint in the daemon's
format (:mod:`.checkpoint`, its SHA-256 checked), ``checkpoint_out`` leaves one, taken after
the last message and before the end-of-record flush ticks the partly filled last window: the
state a daemon holds at that moment, so that replaying day 1 with ``checkpoint_out`` and then
day 2 with ``checkpoint_in`` gives day 2 the estimates one replay of both days gives it.

Each day is read once (:class:`DayStream`): its first scans give the scan period before the
service is built, the rest streams on from the same read, and the ``/truth/plant`` topic a
virtual plant wrote is kept aside on the way, for the summary's comparison only (the estimator
never sees it).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from softsensor.bus.memory import MemoryBus, MemoryInput, MemoryOutput
from softsensor.bus.transport import INPUT_KINDS
from softsensor.bus.zenoh_bus import (
    Publisher,
    listening_endpoints,
    open_session,
    wait_for_peers,
    zenoh_sides,
)
from softsensor.errors import ConfigError, EstimationError, IngestError, SoftsensorError
from softsensor.files import atomic_path
from softsensor.messages import iso_utc
from softsensor.plantconfig import PlantConfig
from softsensor.recording.day_writer import DEFAULT_CHUNK_SIZE, DayWriter
from softsensor.recording.mcap_day import iter_messages
from softsensor.service.build import make_service
from softsensor.service.bus_recorder import BusRecorder
from softsensor.service.bus_worker import BusWorker
from softsensor.service.checkpoint import CheckpointStore, check_fits, checkpoint_time_ns
from softsensor.service.day_replay import ReplayStats, parse_time, replay_messages
from softsensor.service.estimator_service import EstimatorService, Output
from softsensor.service.replay_summary import DayPart, ReplaySummary
from softsensor.service.settings import ServiceSettings, service_settings
from softsensor.service.warmup import warm_up
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN, TOPIC_TRUTH
from softsensor.windows.accumulator import measured_scan_period

log = logging.getLogger(__name__)

#: No progress for this long [s, wall] while waiting for the bus is an error.
STALL_TIMEOUT_S = 60.0


class FileRecorder:
    """One MCAP file for a :class:`~softsensor.service.bus_recorder.BusRecorder` (no rotation).

    Thread-safe ``write(topic, log_time_ns, body)``; ``tick`` does nothing (the file is
    finished by :meth:`close`).
    """

    def __init__(self, path: str | os.PathLike[str], chunk_size: int = DEFAULT_CHUNK_SIZE):
        self.path = Path(path)
        self._writer = DayWriter(self.path, chunk_size=chunk_size)
        self._lock = threading.Lock()
        self.n_written = 0

    def write(self, topic: str, log_time_ns: int, body: dict[str, Any]) -> None:
        with self._lock:
            self._writer.write(topic, log_time_ns, body)
            self.n_written += 1

    def tick(self) -> None:
        return None

    def close(self) -> None:
        with self._lock:
            self._writer.close()


def _wait(cond: Callable[[], bool], progress: Callable[[], int], what: str) -> None:
    """Wait until ``cond()``; IngestError when ``progress()`` stalls for STALL_TIMEOUT_S."""
    last = progress()
    since = time.monotonic()
    while not cond():
        time.sleep(0.005)
        now = progress()
        if now != last:
            last, since = now, time.monotonic()
        elif time.monotonic() - since > STALL_TIMEOUT_S:
            raise IngestError(f"replay stalled waiting for {what} ({now} so far)")


class DayStream:
    """The one read of a replayed day: the scans and lab results logged in ``[start_ns,
    end_ns)`` to publish, the scan period measured on the first ``n_period`` of its scans
    (:func:`~softsensor.windows.accumulator.measured_scan_period`), and, when ``truth``, the
    ``/truth/plant`` values met on the way (read up to ``horizon_ns`` past the end, so the last
    window's estimate has its truth too).

    Raises :class:`~softsensor.errors.IngestError` naming the file for a missing, corrupt or
    (without ``allow_truncated``) truncated day, or one without scans in the range.
    """

    def __init__(self, day: Path, start_ns: int | None, end_ns: int | None, *,
                 allow_truncated: bool = False, truth: bool = True, horizon_ns: int = 0,
                 n_period: int = 2000) -> None:
        topics = [TOPIC_SCAN, TOPIC_LAB, *([TOPIC_TRUTH] if truth else [])]
        self.day = day
        self.end_ns = end_ns
        self.truth: list[tuple[int, float, float]] = []  #: (time, moisture_out, moisture_in)
        self._it = iter_messages(day, topics=topics, allow_truncated=allow_truncated,
                                 start_ns=start_ns,
                                 end_ns=None if end_ns is None else end_ns + horizon_ns)
        self._head: list[tuple[str, int, dict[str, Any]]] = []
        times: list[int] = []
        for message in self._it:
            self._head.append(message)
            if message[0] == TOPIC_SCAN and self._published(message[1]):
                times.append(message[1])
                if len(times) >= n_period:
                    break
        if not times:
            self.close()
            raise IngestError(f"{day}: no /plant/scan messages in the selected time range")
        self.first_scan_ns = times[0]  #: the first scan to publish [ns]
        self.scan_period_s = measured_scan_period(times)

    def _published(self, t: int) -> bool:
        return self.end_ns is None or t < self.end_ns

    def messages(self) -> Iterator[tuple[str, int, dict[str, Any]]]:
        """The scans and lab results to publish, in log-time order (the truth kept aside)."""
        for topic, t, body in itertools.chain(self._head, self._it):
            if topic == TOPIC_TRUTH:
                mo, mi = body.get("moisture_out"), body.get("moisture_in")
                self.truth.append((t, math.nan if mo is None else float(mo),
                                   math.nan if mi is None else float(mi)))
            elif self._published(t):
                yield topic, t, body

    def close(self) -> None:
        """Close the file (when the replay stopped before its end)."""
        self._it.close()


def day_span(day: Path, allow_truncated: bool = False) -> tuple[int, int]:
    """First and last log time [ns] of ``day``'s scans and lab results (IngestError naming
    the file when it has none)."""
    first = last = None
    for _, t, _ in iter_messages(day, topics=[TOPIC_SCAN, TOPIC_LAB],
                                 allow_truncated=allow_truncated):
        first = t if first is None else first
        last = t
    if first is None or last is None:
        raise IngestError(f"{day}: no /plant/scan messages")
    return first, last


def check_order(days: list[Path], allow_truncated: bool = False) -> None:
    """Refuse days that are not in time order, or that overlap, in one line naming both
    files (a replay is one stream, as the plant lived it)."""
    spans = [(d, *day_span(d, allow_truncated)) for d in days]
    for (a, a0, a1), (b, b0, b1) in itertools.pairwise(spans):
        if b0 <= a1:
            what = "overlaps" if b1 >= a0 else "comes before"
            raise IngestError(f"{b} ({iso_utc(b0)} .. {iso_utc(b1)}) {what} {a} ({iso_utc(a0)} "
                              f".. {iso_utc(a1)}): give the days in time order, without overlap")


def replay_to_file(day: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
                   out: str | os.PathLike[str], cfg: PlantConfig,
                   *, estimator: str | None = None, rate: float | str = "max",
                   start: int | str | None = None, end: int | str | None = None,
                   allow_truncated: bool = False, settings: ServiceSettings | None = None,
                   report_truth: bool = True,
                   progress: Callable[[int, int], None] | None = None,
                   checkpoint_in: str | os.PathLike[str] | None = None,
                   checkpoint_out: str | os.PathLike[str] | None = None,
                   via_zenoh: bool = False) -> ReplaySummary:
    """Replay ``day`` (one recorded day, or several in time order as one stream) through the
    estimator service into ``out`` (module docstring): in memory, or over two Zenoh sessions
    on loopback with ``via_zenoh``; starting from the checkpoint ``checkpoint_in`` and leaving
    one at ``checkpoint_out`` when given.

    ``progress(window_end_ns, ticks)`` is called after every estimate (on the thread that
    runs the estimator): a long day shows how far it is.

    Raises :class:`~softsensor.errors.IngestError` naming the file for a missing, corrupt or
    (without ``allow_truncated``) truncated day, or days out of order;
    :class:`~softsensor.errors.ConfigError` for a checkpoint that cannot be used; ``out`` is
    then not left behind.
    """
    days, out = _days(day, out, allow_truncated)
    doc, store_out = _checkpoints(days, out, checkpoint_in, checkpoint_out)
    settings = settings or service_settings(cfg)
    start_ns, end_ns = parse_time(start, "--start"), parse_time(end, "--end")
    horizon = int(round(cfg.solver.window * 1e9))

    def stream(d: Path) -> DayStream:
        return DayStream(d, start_ns, end_ns, allow_truncated=allow_truncated,
                         truth=report_truth, horizon_ns=horizon)

    reads = [stream(days[0])]
    try:
        if doc is not None:
            _check_not_after(doc, checkpoint_in, reads[0], settings.max_future_s)
        service = _service(cfg, settings, estimator, reads[0].scan_period_s, doc,
                           checkpoint_in)
        before = dataclasses.replace(service.stats)
        summary = _new_summary(service, days, out)
        # compile every kernel a tick calls before the first message goes out: a first tick
        # that compiles holds the estimator for tens of seconds (which the Zenoh path's wait
        # would call a stall), and the replay's speed is the streaming's
        summary.warmup_s = warm_up(
            lambda: make_service(cfg, settings, estimator, reads[0].scan_period_s),
            cfg).seconds
        t0 = time.monotonic()
        stats, n_recorded = _record(
            _day_messages(summary.parts, reads, stream), out, settings.chunk_size, service,
            _keeper(summary, progress), rate=rate, checkpoint=store_out, via_zenoh=via_zenoh)
    finally:
        for r in reads:
            r.close()
    summary.wall_s = time.monotonic() - t0
    summary.tally(service.stats, before, stats, n_recorded)
    summary.score({r.day: r.truth for r in reads} if report_truth else {})
    return summary


def _days(day: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
          out: str | os.PathLike[str], allow_truncated: bool) -> tuple[list[Path], Path]:
    """The days to replay, each once and in time order, and the output path, checked
    before anything starts (IngestError naming the file)."""
    days = ([Path(day)] if isinstance(day, (str, os.PathLike))
            else [Path(d) for d in day])
    if not days:
        raise IngestError("no recorded day to replay")
    out = Path(out)
    for d in days:
        _check_paths(d, out)
    if len(set(d.resolve() for d in days)) < len(days):
        raise IngestError("a day is given twice: each day is replayed once, in time order")
    if len(days) > 1:
        check_order(days, allow_truncated)
    return days, out


def _checkpoints(days: list[Path], out: Path,
                 checkpoint_in: str | os.PathLike[str] | None,
                 checkpoint_out: str | os.PathLike[str] | None
                 ) -> tuple[dict | None, CheckpointStore | None]:
    """The checkpoint document to start from and the store to leave one in (each None when
    not asked for); ConfigError for a missing one, or one that would overwrite a file."""
    store_out = None
    if checkpoint_out is not None:
        store_out = CheckpointStore(checkpoint_out)
        if store_out.path.resolve() in {out.resolve(), *(d.resolve() for d in days)}:
            raise ConfigError(f"--checkpoint-out {checkpoint_out}: must differ from --out and "
                              f"the days")
    doc = None
    if checkpoint_in is not None:
        doc = CheckpointStore(checkpoint_in).load()
        if doc is None:
            raise ConfigError(f"--checkpoint-in {checkpoint_in}: no such file")
    return doc, store_out


def _check_not_after(doc: dict, where: str | os.PathLike[str] | None, first: DayStream,
                     max_future_s: float) -> None:
    """Refuse a checkpoint whose times lie more than ``max_future_s`` after the first scan
    replayed, in one line (the daemon sets such a one aside): every scan of the day would be
    older than the estimator's windows and dropped (issue 40: a checkpoint saved 34 h after
    the day made 720 scans give 1 tick, exit 0, no warning)."""
    ahead_s = (checkpoint_time_ns(doc) - first.first_scan_ns) / 1e9
    if ahead_s > max_future_s:
        raise ConfigError(f"--checkpoint-in {where}: checkpoint from after the day: its time "
                          f"{iso_utc(checkpoint_time_ns(doc))} is {ahead_s / 3600:.1f} h after "
                          f"the first scan of {first.day.name} ({iso_utc(first.first_scan_ns)};"
                          f" at most service.max_future_s = {max_future_s:g} s); replay the "
                          f"days after it, or without --checkpoint-in")


def _service(cfg: PlantConfig, settings: ServiceSettings, estimator: str | None,
             scan_period_s: float, doc: dict | None,
             where: str | os.PathLike[str] | None) -> EstimatorService:
    """The estimator service of the replay, restored from the checkpoint ``doc`` (read from
    ``where``) when given; ConfigError when it does not fit."""
    service = make_service(cfg, settings, estimator, scan_period_s)
    if doc is not None:
        check_fits(doc, service.unit, service.kind, str(where))
        try:
            service.restore(doc["service"], where=str(where))
        except EstimationError as exc:
            raise ConfigError(str(exc)) from exc
    return service


def _new_summary(service: EstimatorService, days: list[Path], out: Path) -> ReplaySummary:
    """The summary of replaying ``days`` into ``out`` with ``service``, before it starts."""
    return ReplaySummary(day=days[0], out=out, estimator=service.kind,
                         scan_period_s=service.window.scan_period_s,
                         min_good=service.window.min_good,
                         expected_scans=service.window.expected_scans,
                         parts=[DayPart(d) for d in days])


def _keeper(summary: ReplaySummary,
            progress: Callable[[int, int], None] | None) -> Callable[[Output], None]:
    """The worker's output hook: keeps each estimate in ``summary`` and tells ``progress``."""
    def keep(o: Output) -> None:
        if o.kind == "estimate":
            summary.estimates.append((o.time_ns, o.to_body()))
            if progress is not None:
                progress(o.time_ns, len(summary.estimates))

    return keep


def _day_messages(parts: list[DayPart], reads: list[DayStream],
                  stream: Callable[[Path], DayStream]
                  ) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """The messages of every day in turn, counted in its part; each day after the first is
    opened when the one before is done (and added to ``reads``)."""
    for i, part in enumerate(parts):
        if i:
            try:
                reads.append(stream(part.day))
            except IngestError as exc:
                log.warning("%s", exc)  # nothing of this day in --start .. --end
                continue
        for m in reads[-1].messages():
            part.n_replayed += 1
            if part.first_ns is None:
                part.first_ns = m[1]
            part.last_ns = m[1]
            yield m


def _record(messages: Iterator[tuple[str, int, dict[str, Any]]], out: Path, chunk_size: int,
            service: EstimatorService, on_output: Callable[[Output], None], *,
            rate: float | str, checkpoint: CheckpointStore | None,
            via_zenoh: bool) -> tuple[ReplayStats, int]:
    """Stream ``messages`` through the service into the file ``out``: what was replayed, and
    the messages written. An interrupted replay (SIGTERM, a corrupt day) leaves an earlier
    ``out`` as it was."""
    path = _stream_zenoh if via_zenoh else _stream_memory
    with atomic_path(out) as partial:
        recorder = FileRecorder(partial, chunk_size=chunk_size)
        try:
            stats = path(messages, recorder, service, on_output, rate=rate,
                         checkpoint=checkpoint)
        finally:
            recorder.close()
    return stats, recorder.n_written


def _check_paths(day: Path, out: Path) -> None:
    """Refuse, before anything starts, a day that is ``out`` or missing, and an ``out`` that
    is no file in an existing folder."""
    if day.resolve() == out.resolve():
        raise IngestError(f"{out}: --out must differ from the replayed day")
    if out.is_dir() or not out.resolve().parent.is_dir():
        raise IngestError(f"--out {out}: not a file in an existing folder")
    if not day.is_file():
        raise IngestError(f"{day}: no such file")


def _stream_memory(messages: Iterator[tuple[str, int, dict[str, Any]]],
                   recorder: FileRecorder, service: EstimatorService,
                   on_output: Callable[[Output], None], *, rate: float | str,
                   checkpoint: CheckpointStore | None = None) -> ReplayStats:
    """One in-process bus (:class:`~softsensor.bus.memory.MemoryBus`): each message put at
    ``rate`` is recorded, then run through the service on this thread, whose outputs are
    recorded before the next message is put. Nothing is queued or waited for, so the messages
    reach the service in log-time order by construction. ``checkpoint`` as
    :func:`_stream_zenoh`."""
    unit = service.unit
    bus = MemoryBus(unit)
    with BusRecorder(bus, recorder, unit=unit):  # subscribed first: an input, then its outputs
        worker = BusWorker(service, MemoryInput(bus), MemoryOutput(bus),
                           on_output=on_output, thread=False)
        try:
            stats = replay_messages(messages, bus.put, rate=rate)
            _finish(worker, checkpoint, stats.last_ns)
        finally:
            worker.close(checkpoint=False)
    return stats


def _finish(worker: BusWorker, checkpoint: CheckpointStore | None, last_ns: int | None) -> None:
    """After the last message: the service state to ``checkpoint`` (when given), then the
    end-of-record flush of the partly filled last window (module docstring)."""
    service = worker.service
    if checkpoint is not None:
        worker.call(lambda: checkpoint.save(
            service.checkpoint(), saved_at_ns=service.now_ns or last_ns or 1,
            unit=service.unit))
    worker.flush()


def _stream_zenoh(messages: Iterator[tuple[str, int, dict[str, Any]]],
                  recorder: FileRecorder, service: EstimatorService,
                  on_output: Callable[[Output], None], *, rate: float | str,
                  checkpoint: CheckpointStore | None = None) -> ReplayStats:
    """Two Zenoh sessions on loopback, the plant's publishing ``messages`` at ``rate`` and the
    service's estimating and recording; returns once every message and estimate is
    recorded. ``checkpoint``: where the service state is saved after the last message, before
    the end-of-record flush (module docstring)."""
    unit = service.unit
    with open_session(port=0) as svc_session:
        (endpoint,) = listening_endpoints(svc_session)[:1] or (None,)
        if endpoint is None:
            raise SoftsensorError("replay: the service session is not listening")
        with open_session(port=None, connect=[endpoint]) as plant_session:
            if not wait_for_peers(plant_session, timeout=10.0):
                raise SoftsensorError("replay: the Zenoh sessions did not connect on "
                                      "loopback within 10 s")
            bus = BusRecorder(svc_session, recorder, unit=unit)
            worker = BusWorker(service, *zenoh_sides(svc_session, unit),
                               on_output=on_output)
            publisher = Publisher(plant_session, unit)
            try:
                publisher.declare(INPUT_KINDS)
                if not publisher.wait_matched(INPUT_KINDS, timeout=10.0):
                    raise SoftsensorError("replay: no subscriber matched within 10 s")
                labs_sent = [0]

                def _sink(kind: str, body: dict[str, Any], time_ns: int) -> None:
                    publisher.put(kind, body, time_ns)
                    if kind == "lab":  # the next scan must not overtake it (module docstring)
                        labs_sent[0] += 1
                        _wait(lambda: worker.n_labs_received >= labs_sent[0],
                              lambda: worker.n_labs_received, "a lab result")

                stats = replay_messages(messages, _sink, rate=rate)
                n = stats.n_published
                _wait(lambda: worker.n_in >= n and bus.n_received >= n,
                      lambda: worker.n_in + bus.n_received, "the replayed messages")
                _finish(worker, checkpoint, stats.last_ns)
                _wait(lambda: bus.n_received >= n + worker.n_out,
                      lambda: bus.n_received, "the estimates to be recorded")
            finally:
                publisher.close()
                worker.close(checkpoint=False)
                bus.close()
    return stats


__all__ = ["DayStream", "FileRecorder", "check_order", "day_span", "replay_to_file"]
