"""Laboratory results: from the bus and from files dropped in a watched folder.

Two ways in, one check:

* a JSON body on ``plant/<unit>/lab``: ``{"sample_time_ns": int, "moisture_out": float,
  "sample_id": str}`` (plus ``time_ns``, the time the result became available), checked by
  :func:`softsensor.messages.lab_from_body` (the parser the recorded days use too);
* a file dropped in a folder, CSV or JSON, read by :mod:`softsensor.ingest.lab_files` (its
  layout, the plant config's ``[lab]`` table, and the rules for untrusted files are there).

:class:`LabInput` ignores (and logs) a ``sample_id`` it has seen before; an id is seen once its
result was delivered, and freed again when the estimator refuses that result
(:meth:`LabInput.forget`, :meth:`LabFolderWatcher.forget`: a result outside the envelope or
an outlier, issue 40), so the corrected result with the same id is taken, from a file as from
the bus.

:class:`LabFolderWatcher` polls the folder (no extra dependency). A file is taken whole or not
at all: every entry usable, it goes to ``processed/`` and its new results to the estimator; any
entry unusable, the whole file goes to ``rejected/`` with ``<name>.reason.txt`` saying which
row and why, and nothing of it is applied (fix it and drop it again). The lab input's rate
limit (``[service] max_lab_rate_per_h``) and the estimator's bound on results waiting for one
tick are respected here rather than met downstream, where a result beyond them would be dropped
after being marked seen: a file whose new results exceed what the rate allows now waits in the
folder for a later poll, and one holding more than :data:`BURST` new results (more than the
folder ever hands on at once) is rejected whole.
A file is read only once it is complete: its size, modification time and inode unchanged
over ``settle_s`` of the watcher's own polls (a file first seen is never read at once, however
old its time: a LIMS export paused mid-file for more than ``settle_s`` was taken at the pause),
and unchanged by the reading. A writer can pause for longer than any settle interval, so a file
taken is watched in ``processed/`` for ``watch_s`` more: when it changes there (a writer that
kept it open wrote on) it is read again once settled, and its new results are applied (issue
31 item 4: the rows after a pause were lost, never in ``.seen-ids``, never logged), within
the rate and :data:`BURST` as a fresh file's: what is beyond them is said in the log line and
taken at later polls (issue 40: more than 25 rows appended were lost without a line).

The folder is a boundary: anyone who can write to it is untrusted. Any failure to read a file
rejects it with a short reason that names the row and the column, never any of the file's
content; a link is moved to ``rejected/`` as a link. Accepted ``sample_id`` values are
remembered in ``.seen-ids`` in the folder, so a file dropped again after a restart is still
a duplicate; an id the estimator refused is written there as ``{"refused": id}`` after it,
so it stays free across a restart.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import shutil
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import tzinfo
from pathlib import Path
from typing import Any

from softsensor.errors import IngestError, one_line
from softsensor.files import atomic_path
from softsensor.ingest.historian_map import DEFAULT_LAB_MAP, LabMap
from softsensor.ingest.lab_files import MAX_BYTES, parse_lab_file, read_untrusted
from softsensor.log_throttle import Throttle
from softsensor.messages import LabResult, lab_from_body

log = logging.getLogger(__name__)

#: Most new results taken from the folder at once, and per estimator window after that
#: (:func:`folder_rate`): half the 50 lab results the estimator holds for one tick, leaving
#: the rest to lab results on the bus.
BURST = 25
#: Sample ids remembered across restarts (the newest), in ``.seen-ids`` of the folder.
SEEN_IDS_KEPT = 20_000
#: Longest reason line written to ``rejected/`` and the log [characters].
REASON_CHARS = 300


# ----------------------------------------------------------------------------------------------
# Deduplication and delivery


class LabInput:
    """Checks lab results from any source and hands each new one to ``sink`` once.

    ``submit`` returns ``None`` when the result was delivered, else the reason it was not
    (a duplicate ``sample_id``). Thread-safe: the bus and the folder watcher may share one.
    """

    def __init__(self, sink: Callable[[LabResult], None], *,
                 known_ids: Iterable[str] = (), clock: Callable[[], int] = time.time_ns) -> None:
        self._sink = sink
        self._seen: set[str] = set(known_ids)
        self._lock = threading.Lock()
        self._throttle = Throttle()  # a peer may repeat a bad or duplicate result endlessly
        self.clock = clock
        self.n_accepted = 0
        self.n_duplicates = 0
        self.n_rejected = 0

    def remember(self, sample_ids: Iterable[str]) -> None:
        """Treat ``sample_ids`` as delivered already (ids of earlier runs)."""
        with self._lock:
            self._seen.update(sample_ids)

    def forget(self, sample_id: str) -> bool:
        """Free ``sample_id``: its result was refused downstream, a corrected one may come.
        False when it was not seen here (a result from another sender on the bus)."""
        with self._lock:
            if sample_id not in self._seen:
                return False
            self._seen.discard(sample_id)
            return True

    def seen(self, sample_id: str) -> bool:
        """True when a result with this ``sample_id`` was delivered (or was known at start)."""
        with self._lock:
            return sample_id in self._seen

    def submit(self, lab: LabResult) -> str | None:
        """Deliver ``lab`` unless its ``sample_id`` was seen; return the reason if not."""
        with self._lock:
            if lab.sample_id in self._seen:
                self.n_duplicates += 1
                reason = f"duplicate sample_id {lab.sample_id!r} ignored"
                self._throttle.log(log, "duplicate", logging.INFO, "lab %s", reason)
                return reason
            self._seen.add(lab.sample_id)
            self.n_accepted += 1
        try:
            self._sink(lab)
        except BaseException:
            with self._lock:  # not delivered: let a retry through
                self._seen.discard(lab.sample_id)
                self.n_accepted -= 1
            raise
        return None

    def from_body(self, body: dict[str, Any], log_time_ns: int | None = None,
                  where: str = "plant/dryer1/lab") -> str | None:
        """Check and submit a bus body; return ``None`` if delivered, else the reason."""
        try:
            lab = lab_from_body(body, log_time_ns, where)
            if lab.log_time_ns is None:  # arrived now (checked against the contract again)
                lab = dataclasses.replace(lab, log_time_ns=self.clock())
        except IngestError as exc:
            with self._lock:
                self.n_rejected += 1
            self._throttle.log(log, "bad body", logging.WARNING, "%s", exc)
            return str(exc)
        return self.submit(lab)


# ----------------------------------------------------------------------------------------------
# Folder watcher


@dataclass
class PollReport:
    """What one poll of the folder did."""

    accepted: list[LabResult] = field(default_factory=list)
    duplicates: list[str] = field(default_factory=list)
    processed: list[Path] = field(default_factory=list)
    rejected: list[Path] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    waiting: list[Path] = field(default_factory=list)


def _write_new(path: Path, text: str) -> None:
    """Create ``path`` (never through an existing file or link someone placed there)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                 0o644)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


def _unique(dest: Path) -> Path:
    if not os.path.lexists(dest):
        return dest
    for n in range(1, 10_000):
        cand = dest.with_name(f"{dest.stem}.{n}{dest.suffix}")
        if not os.path.lexists(cand):
            return cand
    raise IngestError(f"{dest}: too many files of that name")


def folder_rate(max_per_h: float, window_s: float, time_scale: float = 1.0) -> float:
    """Lab results per wall second the folder hands on: the lab rate limit, and at most
    :data:`BURST` per estimator window of ``window_s`` [s], on a clock ``time_scale`` times
    faster than the wall's."""
    return min(max_per_h / 3600.0, BURST / window_s) * time_scale


class _Budget:
    """How many lab results the folder may hand on now: a token bucket of ``rate_per_s``
    (None: no limit) holding at most :data:`BURST`, on the wall clock as the pipeline's."""

    def __init__(self, rate_per_s: float | None, burst: int = BURST,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.rate, self.burst, self.clock = rate_per_s, burst, clock
        self.tokens, self.at = float(burst), clock()

    def available(self) -> float:
        if self.rate is None:
            return math.inf
        now = self.clock()
        self.tokens = min(float(self.burst), self.tokens + (now - self.at) * self.rate)
        self.at = now
        return self.tokens

    def take(self, n: int) -> None:
        if self.rate is not None:
            self.tokens -= n


#: Files taken that are watched in ``processed/`` for changes at most (the newest).
WATCHED_FILES = 256


def _stat_signature(path: Path) -> tuple[int, int, int] | None:
    """Size, modification time [ns] and inode of ``path`` (not followed), None if gone."""
    try:
        st = path.lstat()
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, st.st_ino


@dataclass
class _Sighting:
    """A file's signature and the poll time [s, epoch] since when it has had it."""

    signature: tuple[int, int, int]
    since: float


@dataclass
class _Taken:
    """A file taken: its signature when read, when taken [s, monotonic], the sightings
    of its changes since, and the (sample id, moisture) of every result handed on from it."""

    signature: tuple[int, int, int]
    at: float
    sightings: dict[str, _Sighting] = field(default_factory=dict)
    deferred: int = 0  #: new results read again but beyond the rate: taken at later polls
    # a result the estimator refused frees its id (forget), but the same row read again is
    # not a correction: without this it was handed on at every poll, ahead of the rows after
    submitted: set[tuple[str, float]] = field(default_factory=set)


def _steady(sightings: dict[str, _Sighting], key: str, path: Path, now: float,
            settle_s: float) -> bool:
    """Whether ``path`` kept its signature over ``settle_s`` of polls (tracked in
    ``sightings[key]``) and was modified at least ``settle_s`` before ``now``."""
    sig = _stat_signature(path)
    if sig is None:
        return False
    seen = sightings.get(key)
    if seen is None or seen.signature != sig:
        seen = sightings[key] = _Sighting(sig, now)
    return now - seen.since >= settle_s and now - sig[1] / 1e9 >= settle_s


class LabFolderWatcher:
    """Polls ``folder`` for lab files and feeds their entries to a :class:`LabInput`.

    Parameters
    ----------
    folder : str or Path
        Watched folder; ``processed/`` and ``rejected/`` are created inside it.
    lab_input : LabInput
        Where accepted entries go (with ``log_time_ns`` = the time the file was taken).
    poll_s : float
        Poll period of :meth:`run` / :meth:`start` [s].
    settle_s : float
        A file is read once its size, modification time and inode have stayed the same over
        this long of the watcher's polls and it was modified at least this long ago (module
        docstring) [s].
    watch_s : float
        How long a file taken is watched in ``processed/`` for changes, read again when it
        changed [s].
    zone : tzinfo or str, optional
        The plant's clock, for ISO times without an offset (UTC when None).
    lab_map : LabMap
        The files' layout: the plant config's ``[lab]`` table
        (:mod:`softsensor.ingest.lab_files`).
    rate_per_s : float, optional
        Lab results per wall second the estimator takes (:func:`folder_rate`); files beyond
        it wait. None: no limit.
    on_reject : callable, optional
        Called with the first reason line of every file rejected (the daemon counts it and
        says it in health: a LIMS whose every file is refused must not look like a quiet lab).
    """

    def __init__(self, folder: str | os.PathLike[str], lab_input: LabInput, *,
                 poll_s: float = 2.0, settle_s: float = 1.0,
                 zone: tzinfo | str | None = None, lab_map: LabMap = DEFAULT_LAB_MAP,
                 rate_per_s: float | None = None, watch_s: float = 600.0,
                 on_reject: Callable[[str], None] | None = None) -> None:
        self.folder = Path(folder)
        self.on_reject = on_reject
        self.zone = zone  # the clock of ISO times without an offset (the plant's)
        self.lab_map = lab_map
        self.budget = _Budget(rate_per_s)
        #: lines a broken folder or disk would repeat every poll (issue 49: "cannot list
        #: folder: Too many open files" 1,064 times a minute) come once in a while, counted
        self._throttle = Throttle()
        self.processed_dir = self.folder / "processed"
        self.rejected_dir = self.folder / "rejected"
        for d in (self.processed_dir, self.rejected_dir):
            try:
                d.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise IngestError(f"{d}: cannot create folder: {exc.strerror}") from exc
        self.lab_input = lab_input
        self.poll_s = poll_s
        self.settle_s = settle_s
        self.watch_s = watch_s
        self._sightings: dict[str, _Sighting] = {}  # files in the folder, by name
        self._taken: dict[Path, _Taken] = {}  # files in processed/ still watched
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.seen_ids_file = self.folder / ".seen-ids"
        self._ids_lock = threading.Lock()  # the watcher's thread and the estimator's write it
        self._n_seen_lines = self._load_seen_ids()

    # -- sample ids remembered across restarts

    def _load_seen_ids(self) -> int:
        """Hand the ids of ``.seen-ids`` to the lab input; the number of lines read."""
        try:
            data = read_untrusted(self.seen_ids_file, 64 * MAX_BYTES)
        except IngestError as exc:
            if self.seen_ids_file.exists() or self.seen_ids_file.is_symlink():
                log.warning("lab sample ids of earlier runs not read: %s", exc)
            return 0
        ids: dict[str, None] = {}
        lines = data.decode("utf-8", "replace").splitlines()[-SEEN_IDS_KEPT:]
        for line in lines:
            try:
                value = json.loads(line)
            except ValueError:
                continue
            if isinstance(value, str):
                ids[value] = None
            elif isinstance(value, dict) and isinstance(value.get("refused"), str):
                ids.pop(value["refused"], None)
        self.lab_input.remember(ids)
        return len(lines)

    def forget(self, sample_id: str) -> None:
        """Free ``sample_id`` (its result was refused downstream), also across restarts."""
        if self.lab_input.forget(sample_id):
            self._append_id({"refused": sample_id}, sample_id)

    def _remember(self, sample_id: str) -> None:
        """Append an accepted id to ``.seen-ids`` (rewritten to the newest when it grows)."""
        self._append_id(sample_id, sample_id)

    def _append_id(self, record: str | dict[str, str], sample_id: str) -> None:
        try:
            with self._ids_lock:
                self._append_line(json.dumps(record))
        except OSError as exc:
            self._throttle.log(log, "remember", logging.WARNING,
                               "lab sample id %r not remembered: %s", one_line(sample_id, 100),
                               exc.strerror)

    def _append_line(self, line: str) -> None:
        fd = os.open(self.seen_ids_file, os.O_WRONLY | os.O_CREAT | os.O_APPEND
                     | getattr(os, "O_NOFOLLOW", 0), 0o644)
        with os.fdopen(fd, "a", encoding="utf-8") as f:
            f.write(line + "\n")
        self._n_seen_lines += 1
        if self._n_seen_lines > 2 * SEEN_IDS_KEPT:
            lines = self.seen_ids_file.read_text(encoding="utf-8").splitlines()
            with atomic_path(self.seen_ids_file) as tmp:
                tmp.write_text("\n".join(lines[-SEEN_IDS_KEPT:]) + "\n", encoding="utf-8")
            self._n_seen_lines = SEEN_IDS_KEPT

    # -- one poll

    def _candidates(self) -> list[Path]:
        try:
            entries = sorted(self.folder.iterdir())
        except OSError as exc:
            raise IngestError(f"{self.folder}: cannot list folder: {exc.strerror}") from exc
        # links too (they are rejected unread); folders and our own dot files are not inputs
        return [p for p in entries if (p.is_symlink() or p.is_file())
                and not p.name.startswith((".", "~"))
                and not p.name.endswith((".tmp", ".part", ".partial", ".swp"))]

    def _settled(self, path: Path, now: float) -> bool:
        """True once ``path`` has kept its :func:`_stat_signature` over ``settle_s`` of polls and
        was modified at least ``settle_s`` ago."""
        return _steady(self._sightings, path.name, path, now, self.settle_s)

    def _reject(self, path: Path, reasons: list[str], report: PollReport) -> None:
        reasons = [one_line(r, REASON_CHARS) for r in reasons]
        dest = _unique(self.rejected_dir / path.name)
        os.rename(path, dest)  # a link is moved as a link
        _write_new(_unique(dest.with_name(dest.name + ".reason.txt")),
                   "\n".join(reasons) + "\n")
        report.rejected.append(dest)
        report.reasons.extend(reasons)
        for r in reasons:  # a flood of bad files must not become a flood of lines
            self._throttle.log(log, "rejected", logging.WARNING, "lab file rejected: %s", r)
        if self.on_reject is not None:
            try:
                self.on_reject(reasons[0])
            except Exception:  # noqa: BLE001 - the file is handled; the news must not undo it
                log.exception("telling a rejected lab file failed")

    def _handle(self, path: Path, report: PollReport) -> bool:
        """Take one settled file whole or not at all; False when it waits for the rate."""
        now_ns = self.lab_input.clock()
        before = _stat_signature(path)
        try:
            parsed = parse_lab_file(path, log_time_ns=now_ns, zone=self.zone,
                                    lab_map=self.lab_map)
        except IngestError as exc:
            self._reject(path, [f"{exc}; nothing of the file was applied"], report)
            return True
        except Exception as exc:  # noqa: BLE001 - untrusted input: never retried forever
            self._reject(path, [f"{path.name}: unusable file ({type(exc).__name__}); nothing "
                                "of the file was applied"], report)
            return True
        if _stat_signature(path) != before:  # written to while being read: not complete
            report.waiting.append(path)
            return True
        fresh = [lab for lab in parsed.results if not self.lab_input.seen(lab.sample_id)]
        if len(fresh) > BURST:
            self._reject(path, [f"{path.name}: {len(fresh)} new results, more than the {BURST} "
                                "the estimator takes at once (service.max_lab_rate_per_h); "
                                "split the file; nothing of it was applied"], report)
            return True
        if len(fresh) > self.budget.available():
            report.waiting.append(path)  # kept whole for a later poll, nothing marked seen
            return False
        self.budget.take(len(fresh))
        for lab in parsed.results:
            reason = self.lab_input.submit(lab)
            if reason is None:
                report.accepted.append(lab)
                self._remember(lab.sample_id)
            else:
                report.duplicates.append(lab.sample_id)
        if parsed.rows_without_result:
            log.info("lab file %s: %d rows without a result skipped", one_line(path.name, 100),
                     parsed.rows_without_result)
        dest = _unique(self.processed_dir / path.name)
        shutil.move(str(path), dest)
        report.processed.append(dest)
        self._watch(dest, before, {(lab.sample_id, lab.moisture_out) for lab in parsed.results})
        return True

    # -- files taken, watched for changes

    def _watch(self, dest: Path, signature: tuple[int, int, int] | None,
               submitted: set[tuple[str, float]]) -> None:
        """Watch ``dest`` (taken with ``signature``, its results ``submitted``) for
        :attr:`watch_s`; the newest :data:`WATCHED_FILES` at most."""
        if signature is None:
            return
        self._taken[dest] = _Taken(signature, time.monotonic(), submitted=submitted)
        while len(self._taken) > WATCHED_FILES:
            del self._taken[next(iter(self._taken))]

    def _recheck_taken(self, now: float, report: PollReport) -> None:
        """Read again the files taken that changed since (once settled); new results on."""
        for dest, taken in list(self._taken.items()):
            sig = _stat_signature(dest)
            if sig is None or (time.monotonic() - taken.at > self.watch_s
                               and not taken.deferred):
                del self._taken[dest]
                continue
            if sig == taken.signature and not taken.deferred:
                continue
            if sig != taken.signature and not _steady(taken.sightings, "", dest, now,
                                                      self.settle_s):
                continue  # still being written: read it when it is complete
            try:
                parsed = parse_lab_file(dest, log_time_ns=self.lab_input.clock(),
                                        zone=self.zone, lab_map=self.lab_map)
            except Exception as exc:  # noqa: BLE001 - untrusted input: said once, not retried
                msg = (f"{dest.name}: changed after it was taken and is now unusable "
                       f"({one_line(str(exc), REASON_CHARS)}); the results taken before stay")
                report.reasons.append(msg)
                log.error("lab file %s", msg)
                del self._taken[dest]
                continue
            if _stat_signature(dest) != sig:
                continue  # written to while being read
            # new: an id not seen whose row was not handed on unchanged before (a corrected
            # value under a refused id is new)
            fresh = [lab for lab in parsed.results if not self.lab_input.seen(lab.sample_id)
                     and (lab.sample_id, lab.moisture_out) not in taken.submitted]
            # the rate and the burst as for a fresh file: the first results now, the rest at
            # later polls (a file cannot be refused whole once part of it was taken)
            available = min(self.budget.available(), BURST)
            now_taken = fresh[:int(available)]
            self.budget.take(len(now_taken))
            for lab in now_taken:
                reason = self.lab_input.submit(lab)  # (a sink that raises: tried again)
                taken.submitted.add((lab.sample_id, lab.moisture_out))
                if reason is None:
                    report.accepted.append(lab)
                    self._remember(lab.sample_id)
            deferred = len(fresh) - len(now_taken)
            if deferred:
                report.waiting.append(dest)
            if now_taken or (deferred and not taken.deferred):
                log.warning("lab file %s changed after it was taken (a writer still had it "
                            "open): read again, %d new results applied, %d deferred to later "
                            "polls (service.max_lab_rate_per_h, at most %d at once)",
                            one_line(dest.name, 100), len(now_taken), deferred, BURST)
            taken.signature, taken.deferred = sig, deferred

    def poll_once(self, now: float | None = None) -> PollReport:
        """Handle every settled file in the folder once; ``now`` [s, epoch] for tests."""
        now = time.time() if now is None else now
        report = PollReport()
        self._recheck_taken(now, report)
        candidates = self._candidates()
        present = {p.name for p in candidates}
        self._sightings = {k: v for k, v in self._sightings.items() if k in present}
        for path in candidates:
            if not self._settled(path, now):
                report.waiting.append(path)
                continue
            self._sightings.pop(path.name, None)
            try:
                if not self._handle(path, report):
                    report.waiting.extend(candidates[candidates.index(path) + 1:])
                    break  # the rate is spent: the rest waits, unread, for the next poll
            except OSError as exc:
                msg = f"{path.name}: cannot move or write: {exc}"
                report.reasons.append(msg)
                self._throttle.log(log, "move", logging.ERROR, "%s", msg)
            except Exception as exc:  # noqa: BLE001 - the sink failed: keep the file, retry
                msg = f"{path.name}: left for the next poll, delivery failed: {exc}"
                report.reasons.append(msg)
                report.waiting.append(path)
                self._throttle.log(log, "deliver", logging.ERROR, "%s", msg)
        return report

    # -- loop

    def run(self, stop: threading.Event | None = None, max_polls: int | None = None) -> None:
        """Poll every ``poll_s`` until ``stop`` is set (or ``max_polls`` polls were made)."""
        stop = stop or self._stop
        polls = 0
        while not stop.is_set():
            try:
                self.poll_once()
            except IngestError as exc:  # folder vanished: report and keep trying
                self._throttle.log(log, "list", logging.ERROR, "%s", exc)
            polls += 1
            if max_polls is not None and polls >= max_polls:
                return
            stop.wait(self.poll_s)

    def start(self) -> LabFolderWatcher:
        """Poll in a background thread until :meth:`close`."""
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self.run, name="lab-folder", daemon=True)
            self._thread.start()
        return self

    def close(self, timeout: float = 5.0) -> None:
        """Stop the background thread (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def __enter__(self) -> LabFolderWatcher:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = [
    "BURST",
    "LabFolderWatcher",
    "LabInput",
    "PollReport",
    "folder_rate",
]
