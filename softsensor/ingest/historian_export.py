"""Historian exports into scans (CONTRACT sections 1 and 2).

Pure: tables in (pandas DataFrames, as :mod:`softsensor.ingest.tables` reads them from CSV or
Parquet), SI arrays out, laid out by a :class:`~softsensor.ingest.historian_map.HistorianMap`.
Cells become numbers and times by :mod:`softsensor.ingest.cells` (time zones, bad-value
strings, decimal marks); LIMS files are :mod:`softsensor.ingest.lims`.

* Values are converted to SI by pint (:mod:`softsensor.ingest.units`); an ambient humidity
  given as relative humidity (with the ambient temperature of the same scan) or as a dew point
  becomes a humidity ratio by the model's psychrometrics (:mod:`softsensor.ingest.humidity`).
  Missing and bad cells are both ``null`` in the scan body and counted per signal.
* Every value is checked against its signal's physical range
  (:data:`~softsensor.ingest.units.PHYSICAL_RANGE`): outside it the import stops with one line
  naming the tag, its value in the export's unit and in SI, and the map key to check (or, with
  ``out_of_range = "null"``, the value is bad).
* Scans are kept at the export's own timestamps (no resampling); the wide layout gives one scan
  per row, the long layout one per distinct time of a mapped tag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.ingest.cells import (
    TimeSpec,
    bad_quality,
    column,
    numbers,
    text_cells,
    timestamps_ns,
)
from softsensor.ingest.historian_map import DEFAULT_BAD_VALUES, HistorianMap, SignalMap
from softsensor.ingest.humidity import ratio_from_dew_point, ratio_from_relative_humidity
from softsensor.ingest.units import PHYSICAL_RANGE, to_signal_si, to_unit
from softsensor.jsonable import finite_or_none
from softsensor.messages import iso_utc
from softsensor.signals import SCAN_SIGNALS

#: Largest relative humidity read as a measurement [-]: transmitters overshoot a little.
RH_MAX = 1.05


@dataclass
class ScanTable:
    """Scans converted from an export: times [ns, UTC] and SI values (NaN = null)."""

    times_ns: np.ndarray
    values: dict[str, np.ndarray]
    rows_read: int
    bad: dict[str, int] = field(default_factory=dict)  #: bad-quality values per signal
    missing: dict[str, int] = field(default_factory=dict)  #: empty or absent per signal
    skipped_rows: int = 0  #: long layout: rows of tags the map does not name
    #: per mapped signal, the values as the export wrote them (its unit; NaN = null)
    raw: dict[str, np.ndarray] = field(default_factory=dict)
    #: values outside a signal's physical range, one line each (the import stops on them)
    out_of_range: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.times_ns)

    def body(self, i: int) -> dict[str, float | None]:
        """The ``/plant/scan`` body of scan ``i``: every signal, ``None`` for null."""
        return {name: finite_or_none(self.values[name][i]) for name in SCAN_SIGNALS}

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
        vals, bad = numbers(column(frame, sm.column, key, where), sm.column, bad_strings,
                            src.decimal, where, "source.bad_values", thousands=src.thousands)
        if sm.quality_column is not None:
            q = bad_quality(column(frame, sm.quality_column,
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
    tags = text_cells(column(frame, src.tag_column or "", "source.tag_column", where))
    vals_all, bad_all = numbers(
        column(frame, src.value_column or "", "source.value_column", where),
        src.value_column or "", bad_strings, src.decimal, where, "source.bad_values",
        thousands=src.thousands)
    if src.quality_column is not None:
        q = bad_quality(column(frame, src.quality_column, "source.quality_column", where),
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


def _hint_units_row(exc: IngestError, hmap: HistorianMap) -> IngestError:
    """A failure on the first row of an export without ``skip_rows``: most often the units
    row PI and IP.21 write under the header."""
    text = str(exc)
    if hmap.source.skip_rows == 0 and " row 1:" in text and "decimal comma" not in text:
        return IngestError(f"{text} (a units row under the header? set source.skip_rows = 1)")
    return exc


def _label(sm: SignalMap) -> str:
    return sm.column or sm.tag or "constant"


def _humidity(raw: np.ndarray, sm: SignalMap, T_amb: np.ndarray,
              problems: list[str], when: np.ndarray, where: str) -> np.ndarray:
    """``H_amb`` [kg/kg] from a column of relative humidity or dew point (``sm.quantity``)."""
    if sm.quantity == "dew_point":
        return ratio_from_dew_point(to_unit(raw, sm.unit, "kelvin"), sm.pressure_pa)
    phi = to_unit(raw, sm.unit, "dimensionless")
    with np.errstate(invalid="ignore"):
        outside = np.isfinite(phi) & ((phi < 0.0) | (phi > RH_MAX))
    if outside.any():
        i = int(np.flatnonzero(outside)[0])
        problems.append(f"{where}: {_label(sm)} (signals.H_amb) at {iso_utc(int(when[i]))}: "
                        f"relative humidity {raw[i]:g} {sm.unit} is outside 0..{RH_MAX:.0%} "
                        f"(is signals.H_amb.unit right?)")
        phi = np.where(outside, np.nan, phi)
    return ratio_from_relative_humidity(phi, T_amb, sm.pressure_pa)


def _check_range(name: str, sm: SignalMap, si: np.ndarray, raw: np.ndarray,
                 times: np.ndarray, where: str, problems: list[str]) -> np.ndarray:
    """Mask of the values of ``name`` outside its physical range; a problem line for the
    first of them unless the map says they are bad (``out_of_range = "null"``)."""
    lo, hi = PHYSICAL_RANGE[name]
    with np.errstate(invalid="ignore"):
        outside = np.isfinite(si) & ((si < lo) | (si > hi))
    if outside.any() and sm.out_of_range == "refuse":
        i = int(np.flatnonzero(outside)[0])
        si_unit = SCAN_SIGNALS[name]
        more = int(outside.sum()) - 1
        hint = f"is signals.{name}.unit right?"
        if name == "H_amb" and sm.quantity == "humidity_ratio":
            hint += " A relative humidity needs signals.H_amb.quantity = 'relative_humidity'"
        given = f"{raw[i]:g} {sm.unit}" if math.isfinite(raw[i]) else "its value"
        problems.append(
            f"{where}: {_label(sm)} (signals.{name}) at {iso_utc(int(times[i]))}: {given} is "
            f"{si[i]:.4g} {si_unit}, outside the physical range {lo:g}..{hi:g} {si_unit} of "
            f"{name}{f' (and {more} more values)' if more else ''} ({hint}; or "
            f'out_of_range = "null" drops such values)')
    return outside


def convert_scans(frame: pd.DataFrame, hmap: HistorianMap, where: str, *,
                  strict: bool = True) -> ScanTable:
    """Scans of a historian export ``frame`` laid out by ``hmap`` (see the module doc).

    ``strict``: raise on the first value outside its physical range; otherwise list them
    in :attr:`ScanTable.out_of_range` (what ``import --preview`` shows)."""
    src = hmap.source
    spec = TimeSpec(src.time_column, src.time_zone, src.time_unit, src.time_format, "source",
                    dayfirst=src.dayfirst)
    if len(frame) == 0:
        raise IngestError(f"{where}: no rows after the header")
    bad_strings = frozenset(s.lower() for s in (*DEFAULT_BAD_VALUES, *src.bad_values))
    good = frozenset(s.lower() for s in src.good_quality)
    try:
        t_all = timestamps_ns(column(frame, src.time_column, "source.time_column", where),
                              spec, where)
        if src.layout == "wide":
            times, raw = _wide(frame, hmap, t_all, bad_strings, good, where)
            skipped = 0
        else:
            times, raw, skipped = _long(frame, hmap, t_all, bad_strings, good, where)
    except IngestError as exc:
        raise _hint_units_row(exc, hmap) from exc
    n = len(times)
    out = ScanTable(times_ns=times, values={}, rows_read=len(frame), skipped_rows=skipped)
    n_bad: dict[str, int] = {}
    for name, sm in hmap.signals.items():  # the export's values, per scan
        col = np.full(n, np.nan)
        n_bad[name] = 0
        if sm.constant is not None:
            col[:] = sm.constant
        else:
            vals, bad, pos = raw[name]
            col[pos] = vals
            n_bad[name] = int(bad.sum())
        out.raw[name] = col
    problems: list[str] = []
    for name in SCAN_SIGNALS:  # T_amb before H_amb: a relative humidity needs it
        sm = hmap.signals.get(name)
        si = np.full(n, np.nan)
        if sm is not None:
            if name == "H_amb" and sm.quantity != "humidity_ratio":
                si = _humidity(out.raw[name], sm, out.values["T_amb"], problems, times, where)
            else:
                si = to_signal_si(out.raw[name], sm.unit, name)
            outside = _check_range(name, sm, si, out.raw[name], times, where, problems)
            si = np.where(outside, np.nan, si)
            n_bad[name] += int(outside.sum())
        out.values[name] = si
        out.bad[name] = n_bad.get(name, 0)
        out.missing[name] = int(np.isnan(si).sum()) - out.bad[name]
    out.out_of_range = problems
    if strict and problems:
        raise IngestError(problems[0] + (f" [{len(problems) - 1} more signals outside their "
                                         f"range: softsensor import --preview lists them]"
                                         if len(problems) > 1 else ""))
    return out


__all__ = ["ScanTable", "convert_scans"]
