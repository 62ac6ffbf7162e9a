"""Historian exports and LIMS tables into scans and lab results (CONTRACT sections 1 and 2).

Pure: tables in (pandas DataFrames, as :mod:`softsensor.ingest.tables` reads them from CSV or
Parquet), SI arrays and :class:`~softsensor.messages.LabResult` out, laid out by a
:class:`~softsensor.ingest.historian_map.HistorianMap`.

* Times: ISO-8601 text (or the map's ``time_format``) with an offset is taken as written;
  naive text is local time in the map's IANA zone (``zoneinfo`` rules, so DST shifts are
  right; an hour repeated when clocks go back is resolved from the order of the rows); numeric
  timestamps are since the epoch in the map's ``time_unit``. A time before 2000 or after
  now + 1 day is refused with a hint about the unit.
* Values: numbers, converted to SI by pint (:mod:`softsensor.ingest.units`); empty cells are
  missing; the bad-quality strings of the map (``Bad``, ``I/O Timeout``, ``Shutdown``, ...) and
  rows whose quality is not good are bad. Missing and bad are both ``null`` in the scan body
  and counted per signal. Any other text is refused, so a wrong column is not read as nulls.
* Scans are kept at the export's own timestamps (no resampling); the wide layout gives one scan
  per row, the long layout one per distinct time of a mapped tag.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.ingest.historian_map import (
    DEFAULT_BAD_VALUES,
    TIME_UNITS,
    HistorianMap,
    LabMap,
)
from softsensor.ingest.units import moisture_dry_basis, to_signal_si
from softsensor.messages import LabResult, iso_utc, make_lab_result
from softsensor.signals import SCAN_SIGNALS

#: Earliest plausible time [ns since epoch]: 2000-01-01T00:00:00Z.
EARLIEST_NS = 946_684_800 * 10**9
#: How far after now a time may lie (clock skew between historian and this machine) [ns].
FUTURE_SLACK_NS = 86_400 * 10**9

_OFFSET = re.compile(r"(?:Z|[+-]\d\d:?\d\d)$", re.IGNORECASE)
_NUMERIC = re.compile(r"^[+-]?\d+(?:\.\d*)?(?:[eE][+-]?\d+)?$")


@dataclass(frozen=True)
class TimeSpec:
    """How a time column is written: zone of naive times, unit of numbers, text format."""

    column: str
    zone: str | None
    unit: str | None
    fmt: str | None
    key: str  #: map section the spec comes from, for messages ("source", "lab")


# ----------------------------------------------------------------------------------------------
# Times


def _text(series: pd.Series) -> pd.Series:
    """Cells as trimmed strings, ``""`` for empty or missing."""
    return series.map(lambda v: "" if v is None or (isinstance(v, float) and math.isnan(v))
                      else str(v).strip())


def _check_range(ns: np.ndarray, spec: TimeSpec, where: str, raw: Any = None) -> None:
    latest = time.time_ns() + FUTURE_SLACK_NS
    bad = np.flatnonzero((ns < EARLIEST_NS) | (ns > latest))
    if not len(bad):
        return
    i = int(bad[0])
    side = "before 2000" if ns[i] < EARLIEST_NS else "more than a day in the future"
    msg = (f"{where} row {i + 1}: {spec.column} {raw[i] if raw is not None else ''!s} gives "
           f"{iso_utc(int(ns[i])) if abs(int(ns[i])) < 2**62 else 'an absurd time'}, {side}")
    if spec.unit is not None and raw is not None:
        fits = [u for u, size in TIME_UNITS.items()
                if EARLIEST_NS <= float(raw[i]) * size <= latest]
        hint = f"; as {fits[0]} it would be {iso_utc(int(float(raw[i]) * TIME_UNITS[fits[0]]))}" \
            if fits else ""
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
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise IngestError(f"{where}: {spec.column} local times cannot be placed in "
                          f"{spec.zone} ({first}); export with a UTC offset or in UTC") from exc
    return local[codes]


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
    text = _text(series)
    empty = np.flatnonzero((text == "").to_numpy())
    if len(empty):
        raise IngestError(f"{where} row {int(empty[0]) + 1}: {spec.column} is empty")
    if text.str.match(_NUMERIC).all():
        nums = pd.to_numeric(text)
        return _from_numbers(nums.to_numpy(), spec, where)
    aware = text.str.contains(_OFFSET).to_numpy()
    if aware.any() and not aware.all():
        i = int(np.flatnonzero(aware != aware[0])[0])
        raise IngestError(f"{where} row {i + 1}: {spec.column} {text.iloc[i]!r} mixes times "
                          "with and without a UTC offset")
    fmt = spec.fmt or "ISO8601"
    parsed = pd.to_datetime(text, format=fmt, errors="coerce", utc=bool(aware[0]))
    if parsed.isna().any():
        i = int(np.flatnonzero(parsed.isna().to_numpy())[0])
        raise IngestError(f"{where} row {i + 1}: {spec.column} {text.iloc[i]!r} is not a time "
                          f"in format {fmt} (set {spec.key}.time_format)")
    idx = pd.DatetimeIndex(parsed)
    if idx.tz is None:
        idx = _localize(idx, spec, where)
    ns = idx.tz_convert("UTC").as_unit("ns").asi8
    _check_range(ns, spec, where, text.to_numpy())
    return ns


# ----------------------------------------------------------------------------------------------
# Values


def _values(series: pd.Series, name: str, bad_strings: frozenset[str], decimal: str,
            where: str, bad_key: str) -> tuple[np.ndarray, np.ndarray]:
    """Numbers of a value column and a mask of its bad cells (NaN where missing or bad)."""
    if pd.api.types.is_numeric_dtype(series.dtype) and not pd.api.types.is_bool_dtype(series):
        vals = series.to_numpy(dtype=float)
        bad = np.isinf(vals)
        return np.where(bad, np.nan, vals), bad
    text = _text(series)
    numeric = text.str.replace(",", ".", regex=False) if decimal == "," else text
    nums = pd.to_numeric(numeric.where(numeric != ""), errors="coerce")
    nums = nums.to_numpy(dtype=float, copy=True)
    nonnum = (text != "").to_numpy() & ~np.isfinite(nums)
    bad = np.zeros(len(text), dtype=bool)
    for i in np.flatnonzero(nonnum):
        cell = text.iloc[i]
        if cell.lower() not in bad_strings:
            raise IngestError(f"{where} row {i + 1}: {name} value {cell!r} is neither a number "
                              f"nor a known bad-quality string (add it to {bad_key})")
        bad[i] = True
    nums[bad] = np.nan
    return nums, bad


def _bad_quality(series: pd.Series, good: frozenset[str]) -> np.ndarray:
    text = _text(series).str.lower()
    return ((text != "") & ~text.isin(good)).to_numpy()


def _column(frame: pd.DataFrame, name: str, key: str, where: str) -> pd.Series:
    if name not in frame.columns:
        cols = ", ".join(map(str, frame.columns[:12])) + (", ..." if frame.shape[1] > 12 else "")
        raise IngestError(f"{where}: column {name!r} of {key} is not in the file "
                          f"(columns: {cols})")
    return frame[name]


@dataclass
class ScanTable:
    """Scans converted from an export: times [ns, UTC] and SI values (NaN = null)."""

    times_ns: np.ndarray
    values: dict[str, np.ndarray]
    rows_read: int
    bad: dict[str, int] = field(default_factory=dict)  #: bad-quality values per signal
    missing: dict[str, int] = field(default_factory=dict)  #: empty or absent per signal
    skipped_rows: int = 0  #: long layout: rows of tags the map does not name

    def __len__(self) -> int:
        return len(self.times_ns)

    def body(self, i: int) -> dict[str, float | None]:
        """The ``/plant/scan`` body of scan ``i``: every signal, ``None`` for null."""
        out: dict[str, float | None] = {}
        for name in SCAN_SIGNALS:
            v = float(self.values[name][i])
            out[name] = v if math.isfinite(v) else None
        return out

    def period_s(self) -> tuple[float, bool]:
        """Median spacing of the scans [s] and whether it is regular (all within 1 %)."""
        if len(self.times_ns) < 2:
            return math.nan, True
        d = np.diff(self.times_ns) / 1e9
        med = float(np.median(d))
        return med, bool(np.all(np.abs(d - med) <= 0.01 * med))


#: Per signal: values, bad flags and the scan each row goes to.
_Raw = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]


def _wide(frame: pd.DataFrame, hmap: HistorianMap, t_all: np.ndarray,
          bad_strings: frozenset[str], good: frozenset[str], where: str
          ) -> tuple[np.ndarray, _Raw]:
    """Scan times and per-signal values of a wide export (one column per signal)."""
    src = hmap.source
    raw: _Raw = {}
    order = np.argsort(t_all, kind="stable")
    times = t_all[order]
    dup = np.flatnonzero(np.diff(times) == 0)
    if len(dup):
        i = int(order[dup[0] + 1])
        raise IngestError(f"{where} row {i + 1}: time {iso_utc(int(t_all[i]))} repeats "
                          "an earlier row")
    pos = np.empty(len(order), dtype=np.int64)
    pos[order] = np.arange(len(order))
    for name, sm in hmap.signals.items():
        if sm.column is None:
            continue
        key = f"signals.{name}.column"
        vals, bad = _values(_column(frame, sm.column, key, where), sm.column, bad_strings,
                            src.decimal, where, "source.bad_values")
        if sm.quality_column is not None:
            q = _bad_quality(_column(frame, sm.quality_column,
                                     f"signals.{name}.quality_column", where), good)
            bad |= q
            vals = np.where(q, np.nan, vals)
        raw[name] = (vals, bad, pos)
    return times, raw


def _long(frame: pd.DataFrame, hmap: HistorianMap, t_all: np.ndarray,
          bad_strings: frozenset[str], good: frozenset[str], where: str
          ) -> tuple[np.ndarray, _Raw, int]:
    """Scan times, per-signal values and the rows of unmapped tags of a long export
    (timestamp, tag, value[, quality])."""
    src = hmap.source
    raw: _Raw = {}
    tags = _text(_column(frame, src.tag_column or "", "source.tag_column", where))
    vals_all, bad_all = _values(
        _column(frame, src.value_column or "", "source.value_column", where),
        src.value_column or "", bad_strings, src.decimal, where, "source.bad_values")
    if src.quality_column is not None:
        q = _bad_quality(_column(frame, src.quality_column, "source.quality_column", where),
                         good)
        bad_all |= q
        vals_all = np.where(q, np.nan, vals_all)
    by_tag = {sm.tag: name for name, sm in hmap.signals.items() if sm.tag is not None}
    mapped = tags.isin(list(by_tag)).to_numpy()
    skipped = int((~mapped).sum())
    times = np.unique(t_all[mapped])
    if not len(times):
        raise IngestError(f"{where}: none of the map's tags ({', '.join(by_tag)}) is in "
                          f"{src.tag_column}")
    for tag, name in by_tag.items():
        rows = np.flatnonzero((tags == tag).to_numpy())
        pos = np.searchsorted(times, t_all[rows])
        if len(np.unique(pos)) != len(pos):
            _, first = np.unique(pos, return_index=True)
            i = int(rows[np.setdiff1d(np.arange(len(pos)), first)[0]])
            raise IngestError(f"{where} row {i + 1}: tag {tag!r} has two values at "
                              f"{iso_utc(int(t_all[i]))}")
        raw[name] = (vals_all[rows], bad_all[rows], pos)
    return times, raw, skipped


def convert_scans(frame: pd.DataFrame, hmap: HistorianMap, where: str) -> ScanTable:
    """Scans of a historian export ``frame`` laid out by ``hmap`` (see the module doc)."""
    src = hmap.source
    spec = TimeSpec(src.time_column, src.time_zone, src.time_unit, src.time_format, "source")
    if len(frame) == 0:
        raise IngestError(f"{where}: no rows after the header")
    bad_strings = frozenset(s.lower() for s in (*DEFAULT_BAD_VALUES, *src.bad_values))
    good = frozenset(s.lower() for s in src.good_quality)
    t_all = timestamps_ns(_column(frame, src.time_column, "source.time_column", where),
                          spec, where)
    if src.layout == "wide":
        times, raw = _wide(frame, hmap, t_all, bad_strings, good, where)
        skipped = 0
    else:
        times, raw, skipped = _long(frame, hmap, t_all, bad_strings, good, where)
    n = len(times)
    out = ScanTable(times_ns=times, values={}, rows_read=len(frame), skipped_rows=skipped)
    for name in SCAN_SIGNALS:
        sm = hmap.signals.get(name)
        col = np.full(n, np.nan)
        n_bad = 0
        if sm is not None and sm.constant is not None:
            col[:] = to_signal_si(np.array([sm.constant]), sm.unit, name)[0]
        elif sm is not None:
            vals, bad, pos = raw[name]
            col[pos] = to_signal_si(vals, sm.unit, name)
            n_bad = int(bad.sum())
        out.values[name] = col
        out.bad[name] = n_bad
        out.missing[name] = int(np.isnan(col).sum()) - n_bad
    return out


# ----------------------------------------------------------------------------------------------
# Lab results


@dataclass
class LabTable:
    """Lab results converted from a LIMS table, and how many rows had no usable result."""

    results: list[LabResult]
    rows_read: int
    bad: int  #: rows whose moisture was empty or a bad-quality string


def convert_labs(frame: pd.DataFrame, lab: LabMap, default_zone: str | None,
                 where: str) -> LabTable:
    """Lab results [kg/kg dry basis] of a LIMS ``frame``, logged when they became available."""
    if len(frame) == 0:
        raise IngestError(f"{where}: no rows after the header")
    zone = lab.time_zone or default_zone
    sample = timestamps_ns(
        _column(frame, lab.sample_time_column, "lab.sample_time_column", where),
        TimeSpec(lab.sample_time_column, zone, lab.time_unit, lab.time_format, "lab"), where)
    if lab.available_column is not None:
        avail = timestamps_ns(
            _column(frame, lab.available_column, "lab.available_column", where),
            TimeSpec(lab.available_column, zone, lab.time_unit, lab.time_format, "lab"), where)
    else:
        avail = sample + int(round((lab.delay_min or 0.0) * 60e9))
    bad_strings = frozenset(s.lower() for s in DEFAULT_BAD_VALUES)
    raw, bad = _values(_column(frame, lab.moisture_column, "lab.moisture_column", where),
                       lab.moisture_column, bad_strings, lab.decimal, where, "the LIMS export")
    dry = moisture_dry_basis(raw, lab.unit, lab.basis)
    ids = (_text(_column(frame, lab.sample_id_column, "lab.sample_id_column", where))
           if lab.sample_id_column else None)
    results: list[LabResult] = []
    n_bad = 0
    for i in range(len(frame)):
        if np.isnan(raw[i]):
            n_bad += 1
            continue
        at = f"{where} row {i + 1}"
        if not math.isfinite(dry[i]):
            raise IngestError(f"{at}: {lab.moisture_column} {raw[i]:g} {lab.unit} on a wet "
                              "basis leaves no dry fibre (is lab.basis right?)")
        if avail[i] < sample[i]:
            raise IngestError(f"{at}: result available at {iso_utc(int(avail[i]))}, before "
                              f"the sample was taken ({iso_utc(int(sample[i]))})")
        sid = ids.iloc[i] if ids is not None else f"lab-{iso_utc(int(sample[i]))}"
        results.append(make_lab_result(int(sample[i]), float(dry[i]), sid,
                                       log_time_ns=int(avail[i]), where=at))
    results.sort(key=lambda r: (r.log_time_ns, r.sample_time_ns))
    return LabTable(results=results, rows_read=len(frame), bad=n_bad)
