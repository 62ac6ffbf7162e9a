"""Cells of an exported table (CSV text or typed Parquet) as numbers and times.

Shared by historian exports (:mod:`.historian_export`) and LIMS files (:mod:`.lims`, also read by
the daemon's lab folder). Pure: pandas Series in, numpy arrays out, one
:class:`~softsensor.errors.IngestError` line naming the file, the row and the column.

* Times: ISO-8601 text (or the map's ``time_format``, or day-first dates with ``dayfirst``)
  with an offset is taken as written; naive text is local time in the map's IANA zone
  (``zoneinfo`` rules, so DST shifts are right; an hour repeated when clocks go back is
  resolved from the order of the rows); numeric timestamps are since the epoch in the map's
  ``time_unit``. A time before 2000 or after now + 1 day is refused with a hint about the unit.
* Values: numbers (with the map's decimal mark and thousands separator); empty cells are
  missing; the bad-quality strings (``Bad Value``, ``I/O Timeout``, ``Shutdown``, ...) are bad.
  Any other text is refused, so a wrong column is not read as nulls.
* The shape of a European spreadsheet export (``;`` between fields, ``,`` as the decimal mark)
  is recognised wherever it breaks the map's defaults: a header that is one column holding
  ``;`` (:func:`delimiter_hint`), a number written ``209,85`` read with ``decimal = "."``;
  the refusal names ``<table>.delimiter`` and ``<table>.decimal`` instead of pointing to the
  bad-value strings or the rows to skip.

``echo=False`` (a file from an untrusted folder) keeps every message free of the file's
content: it names the row and the column the map gave, never a cell or a header.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from pandas.tseries.api import guess_datetime_format

from softsensor.errors import IngestError
from softsensor.ingest.historian_map import TIME_UNITS
from softsensor.messages import iso_utc

#: Earliest plausible time [ns since epoch]: 2000-01-01T00:00:00Z.
EARLIEST_NS = 946_684_800 * 10**9
#: How far after now a time may lie (clock skew between historian and this machine) [ns].
FUTURE_SLACK_NS = 86_400 * 10**9

_OFFSET = re.compile(r"(?:Z|[+-]\d\d:?\d\d)$", re.IGNORECASE)
_NUMERIC = re.compile(r"^[+-]?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?$")
#: A number with a decimal comma, thousands grouped by '.' or not ("209,85", "1.811,92").
_DECIMAL_COMMA = re.compile(r"^[+-]?(?:\d{1,3}(?:\.\d{3})+|\d+),\d+$")
#: Field separators of spreadsheet exports other than the comma.
_OTHER_DELIMITERS: tuple[str, ...] = (";", "\t", "|")


def delimiter_hint(columns: Any, table: str) -> str:
    """A hint (with a leading space) when the header read is one column holding another
    field separator: the ``<table>.delimiter`` (and ``.decimal``) to set; else ``""``."""
    names = [str(c) for c in columns]
    if len(names) != 1:
        return ""
    for d in _OTHER_DELIMITERS:
        if d in names[0]:
            return (f" (the header is one column holding {d!r}: set {table}.delimiter = "
                    f"{d!r}, and {table}.decimal = ',' if its numbers are written 209,85)")
    return ""


@dataclass(frozen=True)
class TimeSpec:
    """How a time column is written: zone of naive times, unit of numbers, text format."""

    column: str
    zone: str | None
    unit: str | None
    fmt: str | None
    key: str  #: map section the spec comes from, for messages ("source", "lab")
    dayfirst: bool = False  #: day-first text dates when no ``fmt`` is given
    echo: bool = True  #: messages may quote the cell


def shown(cell: Any, echo: bool) -> str:
    """`` 'cell'`` for a message, or nothing when the file is not to be echoed."""
    return f" {cell!r}" if echo else ""


def text_cells(series: pd.Series) -> pd.Series:
    """Cells as trimmed strings, ``""`` for empty or missing."""
    return series.map(lambda v: "" if v is None or (isinstance(v, float) and math.isnan(v))
                      else str(v).strip())


def column(frame: pd.DataFrame, name: str, key: str, where: str, echo: bool = True
           ) -> pd.Series:
    """The column ``name`` (from the map's ``key``); IngestError listing the file's columns
    (only when ``echo``: a header is content too)."""
    if name not in frame.columns:
        cols = ""
        if echo:
            cols = " (columns: " + ", ".join(map(str, frame.columns[:12])) + (
                ", ...)" if frame.shape[1] > 12 else ")")
        hint = delimiter_hint(frame.columns, key.split(".")[0])
        raise IngestError(f"{where}: column {name!r} of {key} is not in the file{cols}{hint}")
    return frame[name]


# ----------------------------------------------------------------------------------------------
# Times


def _check_range(ns: np.ndarray, spec: TimeSpec, where: str, raw: Any = None) -> None:
    latest = time.time_ns() + FUTURE_SLACK_NS
    bad = np.flatnonzero((ns < EARLIEST_NS) | (ns > latest))
    if not len(bad):
        return
    i = int(bad[0])
    side = "before 2000" if ns[i] < EARLIEST_NS else "more than a day in the future"
    cell = shown(raw[i], spec.echo) if raw is not None else ""
    when = iso_utc(int(ns[i])) if abs(int(ns[i])) < 2**62 else "an absurd time"
    msg = f"{where} row {i + 1}: {spec.column}{cell} gives {when if spec.echo else 'a time'}, " \
          f"{side}"
    if spec.unit is not None and raw is not None:
        fits = [u for u, size in TIME_UNITS.items()
                if EARLIEST_NS <= float(raw[i]) * size <= latest]
        hint = f"; as {fits[0]} it would be {iso_utc(int(float(raw[i]) * TIME_UNITS[fits[0]]))}" \
            if fits and spec.echo else ""
        msg += f" (is {spec.key}.time_unit = {spec.unit!r} right?{hint})"
    else:
        msg += f" (check {spec.key}.time_column and {spec.key}.time_format)"
    raise IngestError(msg)


def _from_numbers(values: np.ndarray, spec: TimeSpec, where: str) -> np.ndarray:
    if spec.unit is None:
        raise IngestError(f"{where}: {spec.column} holds numbers; {spec.key}.time_unit must say "
                          f"which unit since the epoch ({', '.join(TIME_UNITS)})")
    if not np.all(np.isfinite(values)):
        i = int(np.flatnonzero(~np.isfinite(values))[0])
        raise IngestError(f"{where} row {i + 1}: {spec.column} is empty or not a time")
    size = TIME_UNITS[spec.unit]
    approx = values.astype(float) * size  # checked in float first: int64 would wrap around
    _check_range(approx, spec, where, values)
    if values.dtype.kind in "iu":
        return values.astype(np.int64) * size
    return np.round(approx).astype(np.int64)


def _localize(naive: pd.DatetimeIndex, spec: TimeSpec, where: str) -> pd.DatetimeIndex:
    if spec.zone is None:
        raise IngestError(f"{where}: {spec.column} has times without a UTC offset and the map "
                          f"names no zone: set {spec.key}.time_zone (an IANA name such as "
                          "'Europe/Stockholm', or 'UTC')")
    from zoneinfo import ZoneInfo

    # Localise each run of equal consecutive times once (the long layout repeats a time for
    # every tag), in row order, so that 'infer' can place the hour repeated when clocks go
    # back from the order of the rows (a repeated wall-clock time is not one instant).
    values = naive.asi8
    starts = np.concatenate(([True], values[1:] != values[:-1]))
    codes = np.cumsum(starts) - 1
    try:
        local = naive[starts].tz_localize(ZoneInfo(spec.zone), ambiguous="infer",
                                          nonexistent="raise")
    except (ValueError, TypeError) as exc:  # pytz/pandas Ambiguous/NonExistentTimeError
        first = str(exc).splitlines()[0] if str(exc) and spec.echo else type(exc).__name__
        raise IngestError(f"{where}: {spec.column} local times cannot be placed in "
                          f"{spec.zone} ({first}); export with a UTC offset or in UTC") from exc
    return local[codes]


def _text_format(first: str, spec: TimeSpec) -> str:
    """The format text times are parsed with: the map's, day first as guessed from the first
    cell (a year-first cell is ISO-8601 whatever ``dayfirst`` says), or ISO-8601."""
    if spec.fmt:
        return spec.fmt
    if spec.dayfirst:
        guessed = guess_datetime_format(first, dayfirst=True)
        if guessed and not guessed.startswith("%Y"):
            return guessed
    return "ISO8601"


def timestamps_ns(series: pd.Series, spec: TimeSpec, where: str) -> np.ndarray:
    """The time column ``series`` as int64 ns since the epoch, UTC (see the module doc)."""
    if pd.api.types.is_datetime64_any_dtype(series.dtype):
        idx = pd.DatetimeIndex(series)
        if idx.hasnans:
            i = int(np.flatnonzero(idx.isna())[0])
            raise IngestError(f"{where} row {i + 1}: {spec.column} is empty")
        if idx.tz is None:
            idx = _localize(idx, spec, where)
        ns = idx.tz_convert("UTC").as_unit("ns").asi8
        _check_range(ns, spec, where)
        return ns
    if pd.api.types.is_numeric_dtype(series.dtype) and not pd.api.types.is_bool_dtype(series):
        return _from_numbers(series.to_numpy(), spec, where)
    text = text_cells(series)
    empty = np.flatnonzero((text == "").to_numpy())
    if len(empty):
        raise IngestError(f"{where} row {int(empty[0]) + 1}: {spec.column} is empty")
    if text.str.match(_NUMERIC).all():
        nums = pd.to_numeric(text, errors="coerce")
        return _from_numbers(nums.to_numpy(dtype=float), spec, where)
    aware = text.str.contains(_OFFSET).to_numpy()
    if aware.any() and not aware.all():
        i = int(np.flatnonzero(aware != aware[0])[0])
        raise IngestError(f"{where} row {i + 1}: {spec.column}{shown(text.iloc[i], spec.echo)} "
                          "mixes times with and without a UTC offset")
    fmt = _text_format(text.iloc[0], spec)
    parsed = pd.to_datetime(text, format=fmt, errors="coerce", utc=bool(aware[0]))
    if parsed.isna().any():
        i = int(np.flatnonzero(parsed.isna().to_numpy())[0])
        how = "set time_format" + ("" if spec.dayfirst else ", or dayfirst = true for 31/12/2026")
        raise IngestError(f"{where} row {i + 1}: {spec.column}{shown(text.iloc[i], spec.echo)} "
                          f"is not a time in format {fmt} ({how} in [{spec.key}])")
    idx = pd.DatetimeIndex(parsed)
    if idx.tz is None:
        idx = _localize(idx, spec, where)
    ns = idx.tz_convert("UTC").as_unit("ns").asi8
    _check_range(ns, spec, where, text.to_numpy())
    return ns


# ----------------------------------------------------------------------------------------------
# Values


def numbers(series: pd.Series, name: str, bad_strings: frozenset[str], decimal: str,
            where: str, bad_key: str, *, thousands: str | None = None, echo: bool = True,
            table: str = "source") -> tuple[np.ndarray, np.ndarray]:
    """Numbers of a value column and a mask of its bad cells (NaN where missing or bad);
    ``table``: the map's table of the CSV settings, for the decimal-comma hint."""
    if pd.api.types.is_numeric_dtype(series.dtype) and not pd.api.types.is_bool_dtype(series):
        vals = series.to_numpy(dtype=float)
        bad = np.isinf(vals)
        return np.where(bad, np.nan, vals), bad
    text = text_cells(series)
    numeric = text.str.replace(thousands, "", regex=False) if thousands else text
    numeric = numeric.str.replace(",", ".", regex=False) if decimal == "," else numeric
    numeric = numeric.where(numeric.str.match(_NUMERIC), "")  # no "inf", "0x1A", "1_000"
    nums = pd.to_numeric(numeric.where(numeric != ""), errors="coerce")
    nums = nums.to_numpy(dtype=float, copy=True)
    nonnum = (text != "").to_numpy() & ~np.isfinite(nums)
    bad = np.zeros(len(text), dtype=bool)
    for i in np.flatnonzero(nonnum):
        cell = text.iloc[i]
        if decimal != "," and _DECIMAL_COMMA.match(cell):
            grouped = "." in cell
            raise IngestError(
                f"{where} row {i + 1}: {name} value{shown(cell, echo)} is written with a "
                f"decimal comma: set {table}.decimal = ','"
                + (f" and {table}.thousands = '.'" if grouped else "")
                + f" (a ';'-separated export also needs {table}.delimiter = ';')")
        if cell.lower() not in bad_strings:
            raise IngestError(f"{where} row {i + 1}: {name} value{shown(cell, echo)} is neither "
                              f"a number nor a known bad-quality string (add it to {bad_key})")
        bad[i] = True
    nums[bad] = np.nan
    return nums, bad


def bad_quality(series: pd.Series, good: frozenset[str]) -> np.ndarray:
    """Rows whose quality cell is neither empty nor one of ``good`` (lower case)."""
    text = text_cells(series).str.lower()
    return ((text != "") & ~text.isin(good)).to_numpy()


__all__ = ["EARLIEST_NS", "FUTURE_SLACK_NS", "TimeSpec", "bad_quality", "column", "numbers",
           "shown", "text_cells", "timestamps_ns"]
