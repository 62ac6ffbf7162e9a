"""Laboratory results: from the bus and from files dropped in a watched folder.

Two ways in, one check:

* a JSON body on ``plant/<unit>/lab``: ``{"sample_time_ns": int, "moisture_out": float,
  "sample_id": str}`` (plus ``time_ns``, the time the result became available);
* a file dropped in a folder: CSV with the header ``sample_time,moisture_out,sample_id``
  (``sample_time`` ISO-8601 or ns since the epoch) or JSON (one object or a list of objects
  with ``sample_time`` or ``sample_time_ns``). An ISO time without an offset is the plant's
  clock: the watcher's ``zone`` (the daemon's ``[display] time_zone``, UTC by default), so a
  LIMS writing local time is read right once the zone is set.

Every entry becomes a :class:`~softsensor.messages.LabResult` (``moisture_out`` in kg/kg
dry basis) or is refused with a one-line reason by :func:`softsensor.messages.lab_from_body`
(the parser the recorded days use too): a missing or malformed field, a non-finite
value, a moisture outside 0..2 kg/kg, a sample time before 2000 (seconds given for ns?) or in
the future. :class:`LabInput` ignores (and logs) a ``sample_id`` it has seen before.

:class:`LabFolderWatcher` polls the folder (no extra dependency). A file whose entries are all
usable goes to ``processed/``; a file that cannot be read at all goes to ``rejected/`` with
``<name>.reason.txt``; a file with some bad entries is processed for the good ones and its bad
entries are written to ``rejected/`` (same name) with a reason file listing each one, so
nothing is lost silently. Files still being written (changed within ``settle_s``) wait for the
next poll.

The folder is a boundary: anyone who can write to it is untrusted. A file is opened with
``O_NOFOLLOW`` (a symbolic link is moved to ``rejected/`` without its target being read), must
be a regular file of at most ``max_bytes`` and ``max_rows`` entries, and any failure at all
(not only a malformed entry: a 5000-digit number, JSON nested 100,000 deep) rejects it with a
short reason that names the problem, not the file's content. Accepted ``sample_id`` values are
remembered in ``.seen-ids`` in the folder, so a file dropped again after a restart is still a
duplicate.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import logging
import os
import shutil
import stat
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from datetime import tzinfo
from pathlib import Path
from typing import Any

from softsensor.errors import IngestError, one_line
from softsensor.files import atomic_path
from softsensor.messages import (
    MOISTURE_RANGE,
    LabResult,
    lab_body,
    lab_from_body,
    make_lab_result,
    parse_sample_time,
)

log = logging.getLogger(__name__)

CSV_COLUMNS: tuple[str, ...] = ("sample_time", "moisture_out", "sample_id")
SUFFIXES: tuple[str, ...] = (".csv", ".json")
#: Largest lab file read [bytes]: a LIMS export of a few results is a few kB.
MAX_BYTES = 1024 * 1024
#: Most entries (rows after the header, or JSON objects) a lab file may hold.
MAX_ROWS = 10_000
#: Sample ids remembered across restarts (the newest), in ``.seen-ids`` of the folder.
SEEN_IDS_KEPT = 20_000
#: Longest reason line written to ``rejected/`` and the log [characters]: what an untrusted
#: file made a parser say (a quoted value) cannot fill pages.
REASON_CHARS = 300


@dataclass
class ParsedFile:
    """Entries of one lab file: the good ones, and the bad ones with their reasons."""

    results: list[LabResult] = field(default_factory=list)
    bad: list[tuple[Any, str]] = field(default_factory=list)  # (raw entry, reason)


def parse_lab_csv(text: str, *, log_time_ns: int | None = None,
                  where: str = "lab.csv", zone: tzinfo | None = None) -> ParsedFile:
    """Parse a CSV lab file; :class:`IngestError` if the file as a whole is unusable."""
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")))
    rows: list[list[str]] = []
    lines: list[int] = []
    try:
        for row in reader:
            if any(c.strip() for c in row):
                rows.append(row)
                lines.append(reader.line_num)
    except csv.Error as exc:
        raise IngestError(f"{where} line {reader.line_num}: not CSV ({exc})") from exc
    if not rows:
        raise IngestError(f"{where}: empty file")
    header = [c.strip() for c in rows[0]]
    cols = {name: i for i, name in enumerate(header)}
    if "sample_time" not in cols and "sample_time_ns" in cols:
        cols["sample_time"] = cols["sample_time_ns"]
    missing = [c for c in CSV_COLUMNS if c not in cols]
    if missing:
        raise IngestError(f"{where}: header {','.join(header)!r} lacks {', '.join(missing)} "
                          f"(expected {','.join(CSV_COLUMNS)})")
    if len(rows) == 1:
        raise IngestError(f"{where}: no lab results after the header")
    if len(rows) - 1 > MAX_ROWS:
        raise IngestError(f"{where}: {len(rows) - 1} rows, more than the {MAX_ROWS} a lab "
                          f"file may have")
    out = ParsedFile()
    for n, row in zip(lines[1:], rows[1:], strict=True):
        at = f"{where} line {n}"
        if len(row) != len(header):
            out.bad.append((row, f"{at}: {len(row)} fields, header has {len(header)}"))
            continue
        try:
            out.results.append(make_lab_result(
                row[cols["sample_time"]], row[cols["moisture_out"]], row[cols["sample_id"]],
                log_time_ns=log_time_ns, where=at, zone=zone))
        except IngestError as exc:
            out.bad.append((row, one_line(str(exc), REASON_CHARS)))
        except Exception as exc:  # noqa: BLE001 - untrusted input: any failure is a bad entry
            out.bad.append((row, f"{at}: unusable entry ({type(exc).__name__})"))
    return out


def parse_lab_json(text: str, *, log_time_ns: int | None = None,
                   where: str = "lab.json", zone: tzinfo | None = None) -> ParsedFile:
    """Parse a JSON lab file (one object or a list); :class:`IngestError` if unusable."""
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise IngestError(f"{where}: not valid JSON ({exc.args[0] if exc.args else exc})"
                          ) from exc
    except RecursionError as exc:
        raise IngestError(f"{where}: JSON nested too deeply") from exc
    entries = data if isinstance(data, list) else [data]
    if not entries:
        raise IngestError(f"{where}: empty list of lab results")
    if len(entries) > MAX_ROWS:
        raise IngestError(f"{where}: {len(entries)} entries, more than the {MAX_ROWS} a lab "
                          f"file may have")
    if not isinstance(data, list) and not isinstance(data, dict):
        raise IngestError(f"{where}: a JSON {type(data).__name__}, not an object or a list")
    out = ParsedFile()
    for n, entry in enumerate(entries):
        at = f"{where} entry {n}" if isinstance(data, list) else where
        try:
            out.results.append(lab_from_body(entry, log_time_ns, where=at, zone=zone))
        except IngestError as exc:
            out.bad.append((entry, one_line(str(exc), REASON_CHARS)))
        except Exception as exc:  # noqa: BLE001 - untrusted input: any failure is a bad entry
            out.bad.append((entry, f"{at}: unusable entry ({type(exc).__name__})"))
    return out


def read_untrusted(path: Path, max_bytes: int) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``, opened without following a
    symbolic link (``O_NOFOLLOW``) and without blocking on a FIFO; :class:`IngestError`
    otherwise, saying nothing of what a link points to."""
    flags = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise IngestError(f"{path.name}: a symbolic link, refused (its target is not "
                              f"read)") from exc
        raise IngestError(f"{path.name}: cannot open: {exc.strerror}") from exc
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise IngestError(f"{path.name}: not a regular file, refused")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise IngestError(f"{path.name}: more than {max_bytes} bytes, more than a lab file "
                          f"may have")
    return data


def _write_new(path: Path, text: str) -> None:
    """Create ``path`` (never through an existing file or link someone placed there)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0),
                 0o644)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)


def parse_lab_file(path: str | os.PathLike[str], *, log_time_ns: int | None = None,
                   zone: tzinfo | None = None) -> ParsedFile:
    """Parse a ``.csv`` or ``.json`` lab file; :class:`IngestError` naming the file if unusable.
    ISO times without an offset are on the clock of ``zone`` (UTC when None)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise IngestError(f"{p.name}: unsupported file type {suffix or '(none)'!r} "
                          "(expected .csv or .json)")
    try:
        text = read_untrusted(p, MAX_BYTES).decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise IngestError(f"{p.name}: not UTF-8 text") from exc
    parse = parse_lab_csv if suffix == ".csv" else parse_lab_json
    return parse(text, log_time_ns=log_time_ns, where=p.name, zone=zone)


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
        self.clock = clock
        self.n_accepted = 0
        self.n_duplicates = 0
        self.n_rejected = 0

    def remember(self, sample_ids: Iterable[str]) -> None:
        """Treat ``sample_ids`` as delivered already (ids of earlier runs)."""
        with self._lock:
            self._seen.update(sample_ids)

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
                log.info("lab %s", reason)
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
        except IngestError as exc:
            with self._lock:
                self.n_rejected += 1
            log.warning("%s", exc)
            return str(exc)
        if lab.log_time_ns is None:
            lab = LabResult(lab.sample_time_ns, lab.moisture_out, lab.sample_id, self.clock())
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


def _unique(dest: Path) -> Path:
    if not os.path.lexists(dest):
        return dest
    for n in range(1, 10_000):
        cand = dest.with_name(f"{dest.stem}.{n}{dest.suffix}")
        if not os.path.lexists(cand):
            return cand
    raise IngestError(f"{dest}: too many files of that name")


def _dump_bad_entries(suffix: str, bad: list[tuple[Any, str]], header: list[str] | None) -> str:
    if suffix == ".csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        if header:
            w.writerow(header)
        for row, _ in bad:
            w.writerow(row)
        return buf.getvalue()
    return json.dumps([entry for entry, _ in bad], indent=1, default=str) + "\n"


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
        A file modified less than this long ago, or whose size changed since the last poll,
        is left for the next poll (it may still be being written) [s].
    """

    def __init__(self, folder: str | os.PathLike[str], lab_input: LabInput, *,
                 poll_s: float = 2.0, settle_s: float = 1.0,
                 zone: tzinfo | None = None) -> None:
        self.folder = Path(folder)
        self.zone = zone  # the clock of ISO times without an offset (the plant's)
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
        self._sizes: dict[str, int] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.seen_ids_file = self.folder / ".seen-ids"
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
        ids = []
        for line in data.decode("utf-8", "replace").splitlines()[-SEEN_IDS_KEPT:]:
            try:
                value = json.loads(line)
            except ValueError:
                continue
            if isinstance(value, str):
                ids.append(value)
        self.lab_input.remember(ids)
        return len(ids)

    def _remember(self, sample_id: str) -> None:
        """Append an accepted id to ``.seen-ids`` (rewritten to the newest when it grows)."""
        try:
            fd = os.open(self.seen_ids_file, os.O_WRONLY | os.O_CREAT | os.O_APPEND
                         | getattr(os, "O_NOFOLLOW", 0), 0o644)
            with os.fdopen(fd, "a", encoding="utf-8") as f:
                f.write(json.dumps(sample_id) + "\n")
            self._n_seen_lines += 1
            if self._n_seen_lines > 2 * SEEN_IDS_KEPT:
                lines = self.seen_ids_file.read_text(encoding="utf-8").splitlines()
                with atomic_path(self.seen_ids_file) as tmp:
                    tmp.write_text("\n".join(lines[-SEEN_IDS_KEPT:]) + "\n", encoding="utf-8")
                self._n_seen_lines = SEEN_IDS_KEPT
        except OSError as exc:
            log.warning("lab sample id %r not remembered: %s", sample_id, exc.strerror)

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
        try:
            st = path.lstat()
        except FileNotFoundError:
            return False
        previous = self._sizes.get(path.name)
        self._sizes[path.name] = st.st_size
        return now - st.st_mtime >= self.settle_s and previous in (None, st.st_size)

    def _reject(self, path: Path, reasons: list[str], report: PollReport) -> None:
        reasons = [one_line(r, REASON_CHARS) for r in reasons]
        dest = _unique(self.rejected_dir / path.name)
        os.rename(path, dest)  # a link is moved as a link
        _write_new(_unique(dest.with_name(dest.name + ".reason.txt")),
                   "\n".join(reasons) + "\n")
        report.rejected.append(dest)
        report.reasons.extend(reasons)
        for r in reasons:
            log.warning("lab file rejected: %s", r)

    def _handle(self, path: Path, report: PollReport) -> None:
        now_ns = self.lab_input.clock()
        try:
            parsed = parse_lab_file(path, log_time_ns=now_ns, zone=self.zone)
        except IngestError as exc:
            self._reject(path, [str(exc)], report)
            return
        except Exception as exc:  # noqa: BLE001 - untrusted input: never retried forever
            self._reject(path, [f"{path.name}: unusable file ({type(exc).__name__})"], report)
            return
        for lab in parsed.results:
            reason = self.lab_input.submit(lab)
            if reason is None:
                report.accepted.append(lab)
                self._remember(lab.sample_id)
            else:
                report.duplicates.append(lab.sample_id)
        if parsed.bad:
            header = None
            if path.suffix.lower() == ".csv":
                text = read_untrusted(path, MAX_BYTES).decode("utf-8-sig")
                header = next(csv.reader(io.StringIO(text)), None)
            bad_path = _unique(self.rejected_dir / path.name)
            _write_new(bad_path, _dump_bad_entries(path.suffix.lower(), parsed.bad, header))
            reasons = [reason for _, reason in parsed.bad]
            _write_new(bad_path.with_name(bad_path.name + ".reason.txt"),
                f"{len(parsed.bad)} of {len(parsed.bad) + len(parsed.results)} entries "
                f"rejected; the others were accepted (original in processed/)\n"
                + "\n".join(reasons) + "\n")
            report.rejected.append(bad_path)
            report.reasons.extend(reasons)
            for r in reasons:
                log.warning("lab entry rejected: %s", r)
        dest = _unique(self.processed_dir / path.name)
        shutil.move(str(path), dest)
        report.processed.append(dest)

    def poll_once(self, now: float | None = None) -> PollReport:
        """Handle every settled file in the folder once; ``now`` [s, epoch] for tests."""
        now = time.time() if now is None else now
        report = PollReport()
        candidates = self._candidates()
        present = {p.name for p in candidates}
        self._sizes = {k: v for k, v in self._sizes.items() if k in present}
        for path in candidates:
            if not self._settled(path, now):
                report.waiting.append(path)
                continue
            self._sizes.pop(path.name, None)
            try:
                self._handle(path, report)
            except OSError as exc:
                msg = f"{path.name}: cannot move or write: {exc}"
                report.reasons.append(msg)
                log.error("%s", msg)
            except Exception as exc:  # noqa: BLE001 - the sink failed: keep the file, retry
                msg = f"{path.name}: left for the next poll, delivery failed: {exc}"
                report.reasons.append(msg)
                report.waiting.append(path)
                log.error("%s", msg)
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
                log.error("%s", exc)
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
    "CSV_COLUMNS",
    "MOISTURE_RANGE",
    "LabFolderWatcher",
    "LabInput",
    "ParsedFile",
    "PollReport",
    "lab_body",
    "lab_from_body",
    "make_lab_result",
    "parse_lab_csv",
    "parse_lab_file",
    "parse_lab_json",
    "parse_sample_time",
]
