"""The streaming path, offline: a recorded day through Zenoh into one estimates file.

``softsensor replay DAY.mcap --out EST.mcap`` (CONTRACT section 4) runs::

    replay_day(DAY) -> plant session --Zenoh/TCP loopback--> service session
        -> ServicePipeline (EstimatorService + estimator) -> estimate, health on Zenoh
        -> BusRecorder -> EST.mcap (the replayed scans and labs, the estimates, the health)

Two Zenoh sessions on 127.0.0.1 (free ports, scouting off) stand for the plant side and the
daemon, so the bytes cross a real Zenoh link. Estimates are a function of the day alone: the
service orders lab results and ticks by log time (see :mod:`.estimator_service`), provided
each lab result reaches it before the scans logged after it. At rate ``max`` that cannot be
left to Zenoh's threads, so after publishing a lab result the replayer waits until the
pipeline has queued it (a few per day, microseconds each). Replaying the same day twice, or
replaying what the daemon recorded live, gives the same estimates.

Several days (``softsensor replay day1.mcap day2.mcap ...``) go through the same two sessions
and the same estimator as one stream, as the daemon lives them: the state carries across the
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.bus.zenoh_bus import (
    Publisher,
    listening_endpoints,
    open_session,
    wait_for_peers,
)
from softsensor.errors import ConfigError, EstimationError, IngestError, SoftsensorError
from softsensor.files import atomic_path
from softsensor.messages import iso_utc
from softsensor.plantconfig import PlantConfig
from softsensor.recording.day_writer import DEFAULT_CHUNK_SIZE, DayWriter
from softsensor.recording.mcap_day import iter_messages
from softsensor.service.build import make_service
from softsensor.service.bus_recorder import BusRecorder
from softsensor.service.bus_worker import INPUT_KINDS, ServicePipeline
from softsensor.service.checkpoint import CheckpointStore, check_fits
from softsensor.service.day_replay import ReplayStats, parse_time, replay_messages
from softsensor.service.estimator_service import EstimatorService, Output
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


@dataclass
class ReplaySummary:
    """What a replay did. Times in ns since the epoch, durations in seconds.

    ``wall_s`` is the streaming alone; ``warmup_s`` the estimator's warm-up before it
    (:mod:`.warmup`: numba compiling or loading its kernels).
    """

    day: Path
    out: Path
    estimator: str
    scan_period_s: float = math.nan
    min_good: int = 0
    expected_scans: int = 0
    n_replayed: int = 0
    n_recorded: int = 0
    ticks: int = 0
    stale_ticks: int = 0
    lab_updates: int = 0
    labs_accepted: int = 0
    labs_refused: int = 0
    span_s: float = 0.0
    wall_s: float = 0.0
    warmup_s: float = 0.0
    rmse: dict[str, float] | None = None
    #: values per signal the plausibility limits refused, over the whole day
    inputs_refused: dict[str, int] = field(default_factory=dict)
    #: per signal, the first window's reason (the first value refused and the limits)
    inputs_refused_why: dict[str, str] = field(default_factory=dict)
    estimates: list[tuple[int, dict[str, Any]]] = field(default_factory=list, repr=False)
    parts: list[DayPart] = field(default_factory=list)

    @property
    def speedup(self) -> float:
        """Recorded time span over wall time [-]."""
        return self.span_s / self.wall_s if self.wall_s > 0 else math.inf

    def problem(self) -> tuple[str, str] | None:
        """``("error", why)`` when no tick was estimated from data (every window stale),
        ``("warning", why)`` when more than half were stale, else None."""
        if self.ticks == 0:
            return "error", f"{self.day}: no window was ticked (is the day shorter than one?)"
        share = self.stale_ticks / self.ticks
        if share < 0.5:
            return None
        refused = self._refused_inputs()
        if refused:
            why = f"{self.stale_ticks} of {self.ticks} windows stale: {refused}"
        else:
            why = (f"{self.stale_ticks} of {self.ticks} windows stale: a window needs "
                   f"{self.min_good} good scans of every model input out of the "
                   f"{self.expected_scans} expected at the scan period {self.scan_period_s:g} "
                   f"s (set solver.scan_period if that is not the day's)")
        if self.stale_ticks == self.ticks:
            return "error", f"{self.day}: nothing estimated from data, {why}"
        return "warning", f"{self.day}: {why}"

    def _refused_inputs(self) -> str | None:
        """The inputs the plausibility limits refused in more than half the scans of the day
        expected (what made its windows stale), with why; None when none was."""
        n_scans = self.ticks * self.expected_scans
        many = {k: n for k, n in self.inputs_refused.items() if n > 0.5 * n_scans}
        if not many:
            return None
        parts = "; ".join(f"{k}: {n} values refused ({self.inputs_refused_why.get(k, '')})"
                          for k, n in sorted(many.items(), key=lambda kv: -kv[1]))
        first = max(many, key=many.__getitem__)
        return (f"the plausibility limits refused the inputs: {parts} (is the unit of {first} "
                f"right? softsensor import --preview holds an export against the limits; if "
                f"the plant runs there, set [plausibility.{first}] in the plant config)")

    def line(self) -> str:
        """The one-paragraph summary the verb prints."""
        text = (f"replayed {self.day}: {self.n_replayed} messages over {self.span_s / 3600:.1f} "
                f"h (scan period {self.scan_period_s:g} s) in {self.wall_s:.1f} s "
                f"({self.speedup:,.0f}x real time, after a "
                f"{self.warmup_s:.1f} s warm-up); {self.estimator}: "
                f"{self.ticks} ticks ({self.stale_ticks} stale), {self.lab_updates} lab "
                f"updates ({self.labs_accepted} lab results accepted, {self.labs_refused} "
                f"refused); wrote {self.out} ({self.n_recorded} messages)")
        if self.rmse:
            parts = ", ".join(f"{k} {v:.4f}" for k, v in self.rmse.items())
            text += f"; RMSE against /truth/plant (reporting only): {parts} kg/kg"
        if len(self.parts) > 1:
            text += "; per day: " + "; ".join(p.line() for p in self.parts)
        return text


@dataclass
class DayPart:
    """One day of a several-day replay: its messages, their log-time span, the estimates
    whose window ends fall in it (up to the next day's first message) and their RMSE against
    the day's ``/truth/plant``."""

    day: Path
    n_replayed: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    ticks: int = 0
    rmse: dict[str, float] | None = None

    def line(self) -> str:
        hours = 0.0 if self.first_ns is None or self.last_ns is None \
            else (self.last_ns - self.first_ns) / 3.6e12
        text = f"{self.day}: {self.n_replayed} messages over {hours:.1f} h, {self.ticks} ticks"
        if self.rmse:
            text += " (RMSE " + ", ".join(f"{k} {v:.4f}" for k, v in self.rmse.items()) + ")"
        return text


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


def truth_rmse(truth: list[tuple[int, float, float]],
               estimates: list[tuple[int, dict[str, Any]]],
               max_age_s: float = 60.0) -> dict[str, float] | None:
    """RMSE of ``moisture_out`` and ``moisture_in`` estimates against the ``/truth/plant``
    values ``(time, moisture_out, moisture_in)`` (:attr:`DayStream.truth`).

    Each estimate (window end ``t``) is compared with the last truth value at or before ``t``
    no older than ``max_age_s``. None when the day has no truth. For reporting only.
    """
    if not truth:
        return None
    tt = np.asarray([t for t, _, _ in truth], dtype=np.int64)
    values = np.asarray([(mo, mi) for _, mo, mi in truth], dtype=float)
    out: dict[str, float] = {}
    for j, name in enumerate(("moisture_out", "moisture_in")):
        err = []
        for t, body in estimates:
            v = body.get(name)
            i = int(np.searchsorted(tt, t, side="right")) - 1
            if v is None or i < 0 or t - tt[i] > max_age_s * 1e9 \
                    or not math.isfinite(values[i, j]):
                continue
            err.append(float(v) - values[i, j])
        if err:
            out[name] = float(np.sqrt(np.mean(np.square(err))))
    return out or None


def replay_to_file(day: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
                   out: str | os.PathLike[str], cfg: PlantConfig,
                   *, estimator: str | None = None, rate: float | str = "max",
                   start: int | str | None = None, end: int | str | None = None,
                   allow_truncated: bool = False, settings: ServiceSettings | None = None,
                   report_truth: bool = True,
                   progress: Callable[[int, int], None] | None = None,
                   checkpoint_in: str | os.PathLike[str] | None = None,
                   checkpoint_out: str | os.PathLike[str] | None = None) -> ReplaySummary:
    """Replay ``day`` (one recorded day, or several in time order as one stream) through
    Zenoh and the estimator service into ``out`` (module docstring), starting from the
    checkpoint ``checkpoint_in`` and leaving one at ``checkpoint_out`` when given.

    ``progress(window_end_ns, ticks)`` is called after every estimate (on the estimator's
    thread): a long day shows how far it is.

    Raises :class:`~softsensor.errors.IngestError` naming the file for a missing, corrupt or
    (without ``allow_truncated``) truncated day, or days out of order;
    :class:`~softsensor.errors.ConfigError` for a checkpoint that cannot be used; ``out`` is
    then not left behind.
    """
    days = ([Path(day)] if isinstance(day, (str, os.PathLike))
            else [Path(d) for d in day])
    if not days:
        raise IngestError("no recorded day to replay")
    out = Path(out)
    start_ns, end_ns = parse_time(start, "--start"), parse_time(end, "--end")
    for d in days:
        _check_paths(d, out)
    if len(set(d.resolve() for d in days)) < len(days):
        raise IngestError("a day is given twice: each day is replayed once, in time order")
    if len(days) > 1:
        check_order(days, allow_truncated)
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
    settings = settings or service_settings(cfg)
    horizon = int(round(cfg.solver.window * 1e9))

    def stream(d: Path) -> DayStream:
        return DayStream(d, start_ns, end_ns, allow_truncated=allow_truncated,
                         truth=report_truth, horizon_ns=horizon)

    reads = [stream(days[0])]
    try:
        service = make_service(cfg, settings, estimator, reads[0].scan_period_s)
        if doc is not None:
            where = str(checkpoint_in)
            check_fits(doc, service.unit, service.kind, where)
            try:
                service.restore(doc["service"], where=where)
            except EstimationError as exc:
                raise ConfigError(str(exc)) from exc
        before = dataclasses.replace(service.stats)
        summary = ReplaySummary(day=days[0], out=out, estimator=service.kind,
                                scan_period_s=service.window.scan_period_s,
                                min_good=service.window.min_good,
                                expected_scans=service.window.expected_scans,
                                parts=[DayPart(d) for d in days])
        # compile every kernel a tick calls before the first message goes out: a first tick
        # that compiles holds the estimator thread for tens of seconds, which _wait would call
        # a stall
        summary.warmup_s = warm_up(
            lambda: make_service(cfg, settings, estimator, reads[0].scan_period_s),
            cfg).seconds

        def _keep(o: Output) -> None:
            if o.kind == "estimate":
                summary.estimates.append((o.time_ns, o.to_body()))
                if progress is not None:
                    progress(o.time_ns, len(summary.estimates))

        def messages() -> Iterator[tuple[str, int, dict[str, Any]]]:
            for i, part in enumerate(summary.parts):
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

        t0 = time.monotonic()
        # an interrupted replay (SIGTERM, a corrupt day) leaves an earlier ``out`` as it was
        with atomic_path(out) as partial:
            recorder = FileRecorder(partial, chunk_size=settings.chunk_size)
            try:
                stats = _stream(messages(), recorder, service, _keep, rate=rate,
                                checkpoint=store_out)
            finally:
                recorder.close()
    finally:
        for r in reads:
            r.close()
    summary.wall_s = time.monotonic() - t0
    s = service.stats
    summary.n_replayed = stats.n_published
    summary.n_recorded = recorder.n_written
    summary.ticks, summary.stale_ticks = s.ticks - before.ticks, s.stale_ticks - before.stale_ticks
    summary.lab_updates = s.lab_updates - before.lab_updates
    summary.labs_accepted = s.labs_accepted - before.labs_accepted
    summary.labs_refused = s.labs_refused - before.labs_refused
    for _t, body in summary.estimates:
        for name, n in (body.get("inputs_refused") or {}).items():
            summary.inputs_refused[name] = summary.inputs_refused.get(name, 0) + int(n)
        for name, why in (body.get("inputs_refused_why") or {}).items():
            summary.inputs_refused_why.setdefault(name, str(why))
    if stats.first_ns is not None and stats.last_ns is not None:
        summary.span_s = (stats.last_ns - stats.first_ns) / 1e9
    truth = [x for r in reads for x in r.truth]
    if report_truth:
        summary.rmse = truth_rmse(truth, summary.estimates)
    _per_day(summary, reads if report_truth else [])
    return summary


def _per_day(summary: ReplaySummary, reads: list[DayStream]) -> None:
    """Each day's estimates (window ends from its first message to the next day's) and, with
    the days' truth, their RMSE."""
    parts = [p for p in summary.parts if p.first_ns is not None]
    truths = {r.day: r.truth for r in reads}
    for i, part in enumerate(parts):
        lo = part.first_ns
        hi = parts[i + 1].first_ns if i + 1 < len(parts) else None
        mine = [(t, b) for t, b in summary.estimates if t > lo and (hi is None or t <= hi)]
        part.ticks = len(mine)
        if part.day in truths:
            part.rmse = truth_rmse(truths[part.day], mine)


def _check_paths(day: Path, out: Path) -> None:
    """Refuse, before anything starts, a day that is ``out`` or missing, and an ``out`` that
    is no file in an existing folder."""
    if day.resolve() == out.resolve():
        raise IngestError(f"{out}: --out must differ from the replayed day")
    if out.is_dir() or not out.resolve().parent.is_dir():
        raise IngestError(f"--out {out}: not a file in an existing folder")
    if not day.is_file():
        raise IngestError(f"{day}: no such file")


def _stream(messages: Iterator[tuple[str, int, dict[str, Any]]], recorder: FileRecorder,
            service: EstimatorService, on_output: Callable[[Output], None],
            rate: float | str, checkpoint: CheckpointStore | None = None) -> ReplayStats:
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
            pipeline = ServicePipeline(svc_session, service, unit=unit, on_output=on_output)
            publisher = Publisher(plant_session, unit)
            try:
                publisher.declare(INPUT_KINDS)
                if not publisher.wait_matched(INPUT_KINDS, timeout=10.0):
                    raise SoftsensorError("replay: no subscriber matched within 10 s")
                labs_sent = [0]

                def _sink(kind: str, body: dict[str, Any], time_ns: int) -> None:
                    publisher.put(kind, body, time_ns)
                    if kind == "lab":  # the next scan must not overtake it (see below)
                        labs_sent[0] += 1
                        _wait(lambda: pipeline.n_labs_received >= labs_sent[0],
                              lambda: pipeline.n_labs_received, "a lab result")

                stats = replay_messages(messages, _sink, rate=rate)
                n = stats.n_published
                _wait(lambda: pipeline.n_in >= n and bus.n_received >= n,
                      lambda: pipeline.n_in + bus.n_received, "the replayed messages")
                if checkpoint is not None:
                    last = stats.last_ns
                    pipeline.call(lambda: checkpoint.save(
                        service.checkpoint(), saved_at_ns=service.now_ns or last or 1,
                        unit=unit))
                pipeline.flush()
                _wait(lambda: bus.n_received >= n + pipeline.n_out,
                      lambda: bus.n_received, "the estimates to be recorded")
            finally:
                publisher.close()
                pipeline.close(checkpoint=False)
                bus.close()
    return stats


__all__ = ["DayPart", "DayStream", "FileRecorder", "ReplaySummary", "check_order", "day_span",
           "replay_to_file", "truth_rmse"]
