"""Lab files: a CSV or JSON file of lab results, read as untrusted input.

A file dropped in the lab folder (:mod:`softsensor.ingest.lab_input`) is CSV or JSON (one
object or a list of objects), laid out by the plant config's ``[lab]`` table: the same keys as
the ``[lab]`` section of a historian map (columns, unit, wet or dry basis, time zone, day-first
dates), so the LIMS file that ``softsensor import`` reads is read here too, by the same
converter (:func:`softsensor.ingest.lims.convert_labs`). Without the table the columns are
``sample_time`` (ISO-8601 or ns since the epoch; ``sample_time_ns`` also), ``moisture_out``
[kg/kg dry basis] and ``sample_id``. An ISO time without an offset is on the plant's clock
(the table's ``time_zone``, else the daemon's ``[display] time_zone``).

Anyone who can write to the folder is untrusted. A file is opened with ``O_NOFOLLOW`` (a
symbolic link is refused without its target being read), must be a regular file of at most
:data:`MAX_BYTES` and :data:`MAX_ROWS` entries, and any failure raises
:class:`~softsensor.errors.IngestError` with a short reason that names the row and the
column, never any of the file's content (a hard link to a secret file must not reach the log).
"""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import os
import stat
import time
from dataclasses import dataclass, field
from datetime import tzinfo
from pathlib import Path
from typing import TYPE_CHECKING

from softsensor.errors import IngestError
from softsensor.ingest.historian_map import DEFAULT_LAB_MAP, LabMap
from softsensor.messages import LabResult

if TYPE_CHECKING:
    import pandas as pd

SUFFIXES: tuple[str, ...] = (".csv", ".json")
#: Largest lab file read [bytes]: a LIMS export of a few results is a few kB.
MAX_BYTES = 1024 * 1024
#: Most entries (rows after the header, or JSON objects) a lab file may hold.
MAX_ROWS = 10_000


@dataclass
class ParsedFile:
    """The results of one lab file (every entry usable: a bad one raises)."""

    results: list[LabResult] = field(default_factory=list)
    rows_without_result: int = 0  #: rows with an empty or bad-quality moisture, skipped


def _zone_name(zone: tzinfo | str | None) -> str:
    """An IANA name for the converter (a ZoneInfo's key; UTC when none)."""
    if zone is None:
        return "UTC"
    return zone if isinstance(zone, str) else getattr(zone, "key", None) or str(zone)


def _csv_frame(text: str, where: str, delimiter: str = ",") -> pd.DataFrame:
    """A CSV lab file as text cells (fields split at the ``[lab]`` table's ``delimiter``);
    blank lines skipped."""
    # (with pandas, as parse_lab_text's converter: not with the daemon, issue 49)
    from softsensor.ingest.cells import delimiter_hint

    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")), delimiter=delimiter)
    rows: list[list[str]] = []
    try:
        for row in reader:
            if any(c.strip() for c in row):
                if len(rows) > MAX_ROWS:
                    raise IngestError(f"{where}: more than the {MAX_ROWS} rows a lab file may "
                                      "have")
                if rows and len(row) != len(rows[0]):
                    raise IngestError(f"{where} line {reader.line_num}: {len(row)} fields, "
                                      f"the header has {len(rows[0])}"
                                      f"{delimiter_hint(rows[0], 'lab')}")
                rows.append(row)
    except csv.Error as exc:
        raise IngestError(f"{where} line {reader.line_num}: not CSV") from exc
    if not rows:
        raise IngestError(f"{where}: empty file")
    if len(rows) == 1:
        raise IngestError(f"{where}: no lab results after the header")
    header = [c.strip() for c in rows[0]]
    if len(set(header)) != len(header):
        raise IngestError(f"{where}: the header names a column twice")
    import pandas as pd  # (see parse_lab_text)

    return pd.DataFrame(rows[1:], columns=header, dtype=str)


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError("a number too large for a float")
    return value


def _json_frame(text: str, where: str) -> pd.DataFrame:
    """A JSON lab file (one object or a list of objects of numbers and text) as a table."""
    try:
        data = json.loads(text, parse_float=_finite, parse_constant=_finite)
    except RecursionError as exc:
        raise IngestError(f"{where}: JSON nested too deeply") from exc
    except ValueError as exc:  # JSONDecodeError: its message names a position, not content
        msg = exc.msg if isinstance(exc, json.JSONDecodeError) else "a number not finite"
        raise IngestError(f"{where}: not valid JSON ({msg})") from exc
    if not isinstance(data, (list, dict)):
        raise IngestError(f"{where}: a JSON {type(data).__name__}, not an object or a list")
    entries = data if isinstance(data, list) else [data]
    if not entries:
        raise IngestError(f"{where}: empty list of lab results")
    if len(entries) > MAX_ROWS:
        raise IngestError(f"{where}: more than the {MAX_ROWS} entries a lab file may have")
    for n, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise IngestError(f"{where} entry {n}: a JSON {type(entry).__name__}, not an "
                              "object")
        if not all(isinstance(v, (str, int, float)) and not isinstance(v, bool)
                   and not (isinstance(v, int) and abs(v) >= 2**63) for v in entry.values()):
            raise IngestError(f"{where} entry {n}: values must be numbers or text")
    import pandas as pd  # (see parse_lab_text)

    return pd.DataFrame(entries)


def parse_lab_text(text: str, suffix: str, *, log_time_ns: int | None = None,
                   where: str = "lab.csv", zone: tzinfo | str | None = None,
                   lab_map: LabMap = DEFAULT_LAB_MAP) -> ParsedFile:
    """The results of a lab file's text (``.csv`` or ``.json``), laid out by ``lab_map``,
    logged at ``log_time_ns`` (default now); :class:`IngestError` naming the row (and no
    content) if any entry is unusable."""
    # pandas (and the converter that needs it) is imported by the first lab file, not with the
    # daemon: tens of MB of resident memory a daemon without a lab folder never needs
    from softsensor.ingest.lims import convert_labs

    frame = (_csv_frame(text, where, lab_map.delimiter) if suffix == ".csv"
             else _json_frame(text, where))
    cols = set(frame.columns)
    if lab_map is DEFAULT_LAB_MAP and "sample_time" not in cols and "sample_time_ns" in cols:
        frame = frame.rename(columns={"sample_time_ns": "sample_time"})
    arrived = time.time_ns() if log_time_ns is None else log_time_ns
    table = convert_labs(frame, lab_map, _zone_name(zone), where, log_time_ns=arrived,
                         echo=False, where_key="lab")
    return ParsedFile(results=table.results, rows_without_result=table.bad)


def parse_lab_csv(text: str, *, log_time_ns: int | None = None, where: str = "lab.csv",
                  zone: tzinfo | str | None = None,
                  lab_map: LabMap = DEFAULT_LAB_MAP) -> ParsedFile:
    """A CSV lab file's results (:func:`parse_lab_text`)."""
    return parse_lab_text(text, ".csv", log_time_ns=log_time_ns, where=where, zone=zone,
                          lab_map=lab_map)


def parse_lab_json(text: str, *, log_time_ns: int | None = None, where: str = "lab.json",
                   zone: tzinfo | str | None = None,
                   lab_map: LabMap = DEFAULT_LAB_MAP) -> ParsedFile:
    """A JSON lab file's results (:func:`parse_lab_text`)."""
    return parse_lab_text(text, ".json", log_time_ns=log_time_ns, where=where, zone=zone,
                          lab_map=lab_map)


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



def parse_lab_file(path: str | os.PathLike[str], *, log_time_ns: int | None = None,
                   zone: tzinfo | str | None = None,
                   lab_map: LabMap = DEFAULT_LAB_MAP) -> ParsedFile:
    """Parse a ``.csv`` or ``.json`` lab file; :class:`IngestError` naming the file if unusable.
    ISO times without an offset are on the clock of ``zone`` (UTC when None) unless the
    map names its own."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise IngestError(f"{p.name}: unsupported file type {suffix or '(none)'!r} "
                          "(expected .csv or .json)")
    try:
        text = read_untrusted(p, MAX_BYTES).decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise IngestError(f"{p.name}: not UTF-8 text") from exc
    return parse_lab_text(text, suffix, log_time_ns=log_time_ns, where=p.name, zone=zone,
                          lab_map=lab_map)


__all__ = [
    "MAX_BYTES",
    "MAX_ROWS",
    "SUFFIXES",
    "ParsedFile",
    "parse_lab_csv",
    "parse_lab_file",
    "parse_lab_json",
    "parse_lab_text",
    "read_untrusted",
]
