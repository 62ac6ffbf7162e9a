"""Reading recorded days: MCAP files of JSON messages (CONTRACT section 2).

:func:`read_day` loads a whole day into a :class:`RecordedDay` (scans as a DataFrame of SI
values, lab results, ground truth when present, and every other topic as decoded bodies);
:func:`iter_messages` streams ``(topic, log_time_ns, body)`` in log-time order. Every problem
with the file (missing, not an MCAP, corrupt, truncated, unknown signal) raises
:class:`~softsensor.errors.IngestError` with a one-line message naming the file. A lab body is
parsed by :func:`softsensor.messages.lab_from_body`, the live path's parser: one it refuses is
reported (a warning with its sample id and reason, :attr:`RecordedDay.refused_labs`) and
skipped; the rest of the day is kept. The files are written by
:class:`~softsensor.recording.day_writer.DayWriter`.

Times are nanoseconds since the Unix epoch, UTC, everywhere.
"""

from __future__ import annotations

import json
import logging
import math
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import zstandard
from mcap.exceptions import InvalidMagic, McapError
from mcap.reader import NonSeekingReader, SeekingReader

from softsensor.errors import IngestError
from softsensor.messages import LabResult, lab_from_body, scan_values
from softsensor.messages import is_number as _is_number
from softsensor.signals import SCAN_SIGNALS, TOPIC_LAB, TOPIC_SCAN, TOPIC_TRUTH

if TYPE_CHECKING:  # pandas is imported by the readers only: the daemon writes, never reads
    import pandas as pd

log = logging.getLogger(__name__)

#: Columns of :attr:`RecordedDay.labs`.
LAB_COLUMNS: tuple[str, ...] = ("log_time_ns", "sample_time_ns", "moisture_out", "sample_id")


# ----------------------------------------------------------------------------------------------
# Lab bodies: refused ones are reported and skipped


def _sample_name(body: Any) -> str:
    """The sample id of a lab body for a report, or ``?`` when it has none."""
    sid = body.get("sample_id") if isinstance(body, dict) else None
    return "?" if sid is None else str(sid)


def _recorded_lab(body: Any, log_time_ns: int, where: str, refused: list[str]
                  ) -> LabResult | None:
    """The :class:`LabResult` of a recorded ``/plant/lab`` body, or None when
    :func:`~softsensor.messages.lab_from_body` refuses it (the live path's rule); the reason,
    with the sample id, is appended to ``refused``."""
    try:
        return lab_from_body(body, log_time_ns, where)
    except IngestError as exc:
        refused.append(f"{exc} (sample_id {_sample_name(body)})")
        return None


# ----------------------------------------------------------------------------------------------
# Reading


#: What the mcap reader raises on a cut or damaged file.
_READ_ERRORS = (McapError, struct.error, ValueError, EOFError, OSError, zstandard.ZstdError)


def _not_mcap(path: Path) -> str:
    """The error for a file that is not MCAP, with the way to convert what it likely is."""
    hint = ""
    if path.suffix.lower() in (".csv", ".txt", ".parquet", ".xlsx", ".json"):
        hint = ("; a historian or LIMS export is converted first with `softsensor import "
                "--map MAP.toml --scans FILE --out DAY.mcap` (README: bring your own plant)")
    return f"{path}: not an MCAP file (bad magic bytes){hint}"


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")  # noqa: SIM115 - closed by callers
    except FileNotFoundError as exc:
        raise IngestError(f"{path}: no such file") from exc
    except IsADirectoryError as exc:
        raise IngestError(f"{path}: is a directory, not an MCAP file") from exc
    except OSError as exc:
        raise IngestError(f"{path}: cannot open: {exc.strerror}") from exc


def _decode(path: Path, topic: str, encoding: str, log_time: int, data: bytes) -> Any:
    if encoding != "json":
        raise IngestError(f"{path}: topic {topic} has message encoding {encoding!r}, not json")
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise IngestError(f"{path}: {topic} message at {log_time} ns is not valid JSON") from exc


class _BoundedReads:
    """A file whose reads never ask for more than is left in it: a corrupt record length
    (a cut or overwritten chunk header can say 2**60 bytes) then reads short, which the MCAP
    reader reports as the end of the file, instead of allocating the length it was told."""

    def __init__(self, f: IO[bytes], size: int) -> None:
        self._f, self._size = f, size

    def read(self, n: int = -1) -> bytes:
        left = max(self._size - self._f.tell(), 0)
        return self._f.read(left if n is None or n < 0 else min(n, left))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def _raw_messages(path: Path, topics: list[str] | None, allow_truncated: bool,
                  on_truncated: Callable[[str], None] | None,
                  starting_at: int | None = None, ending_before: int | None = None,
                  ) -> Iterator[tuple[str, int, Any]]:
    """Yield ``(topic, log_time_ns, body)`` in log-time order; see :func:`iter_messages`."""
    f = _open(path)
    with f:
        try:
            reader = SeekingReader(f, validate_crcs=True)
        except _READ_ERRORS as exc:
            raise IngestError(_not_mcap(path)) from exc
        intact = True
        try:
            reader.get_summary()
        except _READ_ERRORS as exc:
            intact = False
            reason = ("truncated or corrupt MCAP file "
                      f"(no valid summary or footer: {type(exc).__name__})")
            if not allow_truncated:
                raise IngestError(f"{path}: {reason}") from exc
        if intact:
            try:
                for _schema, channel, msg in reader.iter_messages(
                        topics=topics, log_time_order=True,
                        starting_at=starting_at, ending_before=ending_before):
                    yield channel.topic, msg.log_time, _decode(
                        path, channel.topic, channel.message_encoding, msg.log_time, msg.data)
            except _READ_ERRORS as exc:
                raise IngestError(f"{path}: corrupt MCAP file ({type(exc).__name__}: "
                                  f"{str(exc).splitlines()[0] if str(exc) else 'bad record'})"
                                  ) from exc
            return
        # Truncated: read linearly every complete message before the cut, then sort.
        f.seek(0)
        got: list[tuple[int, int, str, str, bytes]] = []
        bounded = _BoundedReads(f, path.stat().st_size)
        try:
            for _schema, channel, msg in NonSeekingReader(bounded,
                                                          validate_crcs=True).iter_messages(
                    topics=topics, log_time_order=False,
                    starting_at=starting_at, ending_before=ending_before):
                got.append((msg.log_time, len(got), channel.topic, channel.message_encoding,
                            msg.data))
        except InvalidMagic as exc:
            raise IngestError(_not_mcap(path)) from exc
        except _READ_ERRORS as exc:
            log.warning("%s: truncated after %d complete messages (%s: %s)", path, len(got),
                        type(exc).__name__, exc)
        if on_truncated is not None:
            on_truncated(reason)
        got.sort(key=lambda g: (g[0], g[1]))
        for t, _i, topic, enc, data in got:
            yield topic, t, _decode(path, topic, enc, t, data)


def iter_messages(path: str | os.PathLike[str], topics: Iterable[str] | None = None,
                  allow_truncated: bool = False, *, start_ns: int | None = None,
                  end_ns: int | None = None) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """Stream ``(topic, log_time_ns, body)`` of a recorded day in log-time order.

    ``start_ns`` / ``end_ns`` select the log times ``[start_ns, end_ns)`` [ns since epoch].
    Scan bodies are checked with :func:`scan_values`, so an unknown signal raises
    :class:`IngestError` when its message is reached. Lab bodies are checked with
    :func:`~softsensor.messages.lab_from_body`: a refused one (missing or non-finite moisture,
    malformed field) is skipped with a warning naming its sample id and reason. A truncated
    file raises at once unless ``allow_truncated``, in which case every complete message
    before the cut is yielded (and a warning logged).
    """
    p = Path(path)
    sel = None if topics is None else list(topics)
    for topic, t, body in _raw_messages(p, sel, allow_truncated, None, start_ns, end_ns):
        where = f"{p}: {topic} at {t} ns"
        if topic == TOPIC_SCAN:
            scan_values(body, where)
        elif topic == TOPIC_LAB:
            refused: list[str] = []
            if _recorded_lab(body, t, where, refused) is None:
                log.warning("lab result skipped: %s", refused[0])
                continue
        yield topic, t, body


@dataclass
class RecordedDay:
    """A recorded day loaded into memory.

    Attributes
    ----------
    path : Path
        The MCAP file.
    scans : pandas.DataFrame
        One row per ``/plant/scan`` message, index = log time [ns since epoch, int64], one float
        column per signal of :data:`~softsensor.signals.SCAN_SIGNALS` (SI units), NaN for null
        or missing.
    labs : pandas.DataFrame
        Columns ``log_time_ns``, ``sample_time_ns`` [ns], ``moisture_out`` [kg/kg dry basis],
        ``sample_id``, sorted by log time.
    truth : pandas.DataFrame or None
        Numeric fields of ``/truth/plant`` bodies indexed by log time [ns]; None when absent.
        Nothing that estimates, calibrates or diagnoses may read it.
    truncated : bool
        True when the file was cut short and only the messages before the cut were read.
    messages : dict
        Bodies per topic as ``(log_time_ns, body)``; refused lab bodies are not among them.
    refused_labs : list of str
        One line per ``/plant/lab`` body refused by
        :func:`~softsensor.messages.lab_from_body` (reason and sample id): skipped, not in
        ``labs``, and logged as a warning.
    """

    path: Path
    scans: pd.DataFrame
    labs: pd.DataFrame
    truth: pd.DataFrame | None
    truncated: bool = False
    messages: dict[str, list[tuple[int, dict[str, Any]]]] = field(default_factory=dict)
    refused_labs: list[str] = field(default_factory=list)

    def topic(self, name: str) -> list[tuple[int, dict[str, Any]]]:
        """Messages of one topic as ``(log_time_ns, body)`` in log-time order ([] if absent)."""
        return self.messages.get(name, [])

    @property
    def topics(self) -> list[str]:
        """Topics present in the day."""
        return sorted(self.messages)

    def lab_results(self) -> list[LabResult]:
        """Lab rows as :class:`LabResult` objects, in log-time order."""
        return [LabResult(int(r.sample_time_ns), float(r.moisture_out), str(r.sample_id),
                          int(r.log_time_ns)) for r in self.labs.itertuples(index=False)]

    @property
    def start_ns(self) -> int | None:
        """First scan log time [ns], None without scans."""
        return int(self.scans.index[0]) if len(self.scans) else None

    @property
    def end_ns(self) -> int | None:
        """Last scan log time [ns], None without scans."""
        return int(self.scans.index[-1]) if len(self.scans) else None


def _scans_frame(times: list[int], rows: list[dict[str, float]]) -> pd.DataFrame:
    import pandas as pd

    index = pd.Index(np.asarray(times, dtype=np.int64), name="log_time_ns")
    data = {name: np.fromiter((r[name] for r in rows), dtype=float, count=len(rows))
            for name in SCAN_SIGNALS}
    return pd.DataFrame(data, index=index)


def _labs_frame(labs: list[LabResult]) -> pd.DataFrame:
    import pandas as pd

    return pd.DataFrame({
        "log_time_ns": np.asarray([lab.log_time_ns for lab in labs], dtype=np.int64),
        "sample_time_ns": np.asarray([lab.sample_time_ns for lab in labs], dtype=np.int64),
        "moisture_out": np.asarray([lab.moisture_out for lab in labs], dtype=float),
        "sample_id": pd.Series([lab.sample_id for lab in labs], dtype=str),
    })


def _truth_frame(msgs: list[tuple[int, dict[str, Any]]]) -> pd.DataFrame | None:
    import pandas as pd

    if not msgs:
        return None
    cols: dict[str, list[float]] = {}
    for i, (_t, body) in enumerate(msgs):
        for key, v in body.items():
            if v is None or _is_number(v):
                col = cols.get(key)
                if col is None:
                    col = cols[key] = [math.nan] * len(msgs)
                col[i] = math.nan if v is None else float(v)
    index = pd.Index(np.asarray([t for t, _ in msgs], dtype=np.int64), name="log_time_ns")
    return pd.DataFrame({k: np.asarray(v, dtype=float) for k, v in cols.items()}, index=index)


def read_day(path: str | os.PathLike[str], *, topics: Iterable[str] | None = None,
             allow_truncated: bool = False) -> RecordedDay:
    """Load a recorded day (CONTRACT section 2).

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : iterable of str, optional
        Read only these topics (default: all).
    allow_truncated : bool
        Accept a file cut short (writer killed): keep every complete message before the cut and
        set :attr:`RecordedDay.truncated`. Otherwise such a file raises :class:`IngestError`.
    """
    p = Path(path)
    sel = None if topics is None else list(topics)
    truncated = False

    def _mark(_reason: str) -> None:
        nonlocal truncated
        truncated = True

    scan_t: list[int] = []
    scan_rows: list[dict[str, float]] = []
    labs: list[LabResult] = []
    refused: list[str] = []
    messages: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for topic, t, body in _raw_messages(p, sel, allow_truncated, _mark):
        where = f"{p}: {topic} at {t} ns"
        if topic == TOPIC_SCAN:
            scan_rows.append(scan_values(body, where))
            scan_t.append(t)
        elif topic == TOPIC_LAB:
            lab = _recorded_lab(body, t, where, refused)
            if lab is None:
                continue
            labs.append(lab)
        messages.setdefault(topic, []).append((t, body))
    if refused:
        log.warning("%s: %d lab result(s) refused and skipped: %s", p, len(refused),
                    "; ".join(refused))
    return RecordedDay(
        path=p,
        scans=_scans_frame(scan_t, scan_rows),
        labs=_labs_frame(labs),
        truth=_truth_frame(messages.get(TOPIC_TRUTH, [])),
        truncated=truncated,
        messages=messages,
        refused_labs=refused,
    )


__all__ = [
    "LAB_COLUMNS",
    "RecordedDay",
    "iter_messages",
    "read_day",
]
