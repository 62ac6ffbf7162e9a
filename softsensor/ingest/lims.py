"""LIMS tables into lab results: one format for ``softsensor import`` and the lab folder.

A LIMS file is laid out by a :class:`~softsensor.ingest.historian_map.LabMap`: the ``[lab]``
table of a historian map (``import``) or of the plant config (the daemon's lab folder, which
reads :data:`~softsensor.ingest.historian_map.DEFAULT_LAB_MAP` without one). Its moisture is
in any unit pint reads as a fraction (%, kg/kg, g/kg) on a wet or dry basis and becomes
``moisture_out`` [kg/kg, dry basis] (CONTRACT section 1).

A result is refused, with its row and what to check, when its moisture is missing or leaves no
dry fibre (a wet basis of 100 %), or breaks the lab-result contract of
:mod:`softsensor.messages` (a moisture of zero or outside the plausible range, a sample time
after the result arrived): the message says which map key to check (``unit`` for a % read as
kg/kg, ``time_zone`` for a sample stamped after its file arrived).
``import`` stops at the first such row and quotes it; the lab folder (``echo=False``) refuses
the whole file and quotes nothing of it (anyone may drop a file there, a link to a secret too).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.ingest.cells import TimeSpec, column, numbers, text_cells, timestamps_ns
from softsensor.ingest.historian_map import DEFAULT_BAD_VALUES, LabMap
from softsensor.ingest.units import moisture_dry_basis
from softsensor.messages import (
    EARLIEST_SAMPLE_NS,
    LabResult,
    iso_utc,
    make_lab_result,
    moisture_problem,
    sample_time_problem,
)


@dataclass
class LabTable:
    """Lab results converted from a LIMS table, and how many rows had no usable result."""

    results: list[LabResult]
    rows_read: int
    bad: int  #: rows whose moisture was empty or a bad-quality string
    #: each result's moisture as the file wrote it (in the map's unit and basis), in the
    #: order of ``results``: what ``import --preview`` shows beside the converted value
    raw: list[float] = field(default_factory=list)


def _moisture_problem(raw: float, dry: float, lab: LabMap, where_key: str, echo: bool
                      ) -> str | None:
    """Why a moisture ``raw`` read as ``lab.unit`` on ``lab.basis`` giving ``dry`` [kg/kg] is
    not a measurement (the lab-result contract, :func:`~softsensor.messages.moisture_problem`,
    with the map key to check; the value itself when ``echo``), or None."""
    value = f" ({raw:g} {lab.unit})" if echo else ""
    if not np.isfinite(dry):
        return (f"{lab.moisture_column} on a wet basis leaves no dry fibre (100 % or more: is "
                f"{where_key}.basis right?){value}")
    problem = moisture_problem(dry)
    if problem is None or dry == 0.0:
        return None if problem is None else f"{lab.moisture_column} {problem}{value}"
    hint = (f"set {where_key}.unit = \"%\" and {where_key}.basis" if lab.unit != "%"
            else f"is {where_key}.unit right?")
    return (f"{lab.moisture_column} read as {lab.unit} on a {lab.basis} basis {problem} "
            f"({hint}){value}")


def _time_problem(sample: int, avail: int, lab: LabMap, where_key: str, arrived: bool
                  ) -> str | None:
    """Why ``sample`` [ns] cannot be the sample time of a result available at ``avail`` [ns]
    (the contract's rule, :func:`~softsensor.messages.sample_time_problem`), with the key to
    check: the file's arrival (``arrived``) or the map's available time set it."""
    problem = sample_time_problem(sample, avail)
    if problem is None:
        return None
    if arrived and sample >= EARLIEST_SAMPLE_NS:
        # the arrival is the daemon's clock: name it first (a demo's daemon started after
        # plant-server ran behind the plant's clock; the time zone was a red herring)
        return (f"{lab.sample_time_column} {problem} (at {iso_utc(avail)} by the daemon's "
                f"clock: is that clock the plant's? against plant-server start the daemon with "
                f"--clock-start plc; else is {where_key}.time_zone right?)")
    key = ("time_unit" if sample < EARLIEST_SAMPLE_NS
           else "available_column" if lab.available_column is not None else "delay_min")
    return f"{lab.sample_time_column} {problem} (is {where_key}.{key} right?)"


def convert_labs(frame: pd.DataFrame, lab: LabMap, default_zone: str | None, where: str, *,
                 log_time_ns: int | None = None, echo: bool = True,
                 where_key: str = "lab") -> LabTable:
    """Lab results [kg/kg dry basis] of a LIMS ``frame``, logged when they became available.

    ``log_time_ns``: when the whole file arrived (the lab folder), instead of the map's
    ``available_column`` or ``delay_min``. ``echo=False``: messages quote no cell (module
    doc). ``where_key``: the config table the map came from, for hints (``lab``)."""
    if len(frame) == 0:
        raise IngestError(f"{where}: no rows after the header")
    if log_time_ns is None and lab.available_column is None and lab.delay_min is None:
        raise IngestError(f"{where}: {where_key}.available_column or {where_key}.delay_min "
                          "must say when each result became available")
    cols = _lab_columns(frame, lab, default_zone, where, log_time_ns, echo, where_key)
    results = _lab_results(cols, lab, where, where_key, echo, arrived=log_time_ns is not None)
    results.sort(key=lambda r: (r[0].log_time_ns, r[0].sample_time_ns))
    return LabTable(results=[r for r, _ in results], rows_read=len(frame),
                    bad=int(np.isnan(cols.raw).sum()),  # empty or bad-quality cells: skipped
                    raw=[v for _, v in results])


class _LabColumns(NamedTuple):
    """The cells of a LIMS table, one entry per row: sample and available times [ns], the
    moisture as written (NaN: empty or bad quality) and on a dry basis [kg/kg], the sample
    ids (None without a sample id column)."""

    sample: np.ndarray
    avail: np.ndarray
    raw: np.ndarray
    dry: np.ndarray
    ids: pd.Series | None


def _lab_columns(frame: pd.DataFrame, lab: LabMap, default_zone: str | None, where: str,
                 log_time_ns: int | None, echo: bool, where_key: str) -> _LabColumns:
    """Read and convert the columns the map names (:func:`convert_labs`); a column that is
    missing or unreadable raises :class:`IngestError` naming its map key."""
    zone = lab.time_zone or default_zone

    def times(name: str, key: str) -> np.ndarray:
        spec = TimeSpec(name, zone, lab.time_unit, lab.time_format, where_key,
                        dayfirst=lab.dayfirst, echo=echo)
        return timestamps_ns(column(frame, name, f"{where_key}.{key}", where, echo), spec,
                             where)

    sample = times(lab.sample_time_column, "sample_time_column")
    if log_time_ns is not None:
        avail = np.full(len(frame), int(log_time_ns), dtype=np.int64)
    elif lab.available_column is not None:
        avail = times(lab.available_column, "available_column")
    else:
        avail = sample + int(round((lab.delay_min or 0.0) * 60e9))
    bad_strings = frozenset(s.lower() for s in DEFAULT_BAD_VALUES)
    raw, _ = numbers(column(frame, lab.moisture_column, f"{where_key}.moisture_column",
                            where, echo),
                     lab.moisture_column, bad_strings, lab.decimal, where, "the LIMS export",
                     thousands=lab.thousands, echo=echo, table=where_key)
    dry = moisture_dry_basis(raw, lab.unit, lab.basis)
    ids = (text_cells(column(frame, lab.sample_id_column, f"{where_key}.sample_id_column",
                             where, echo))
           if lab.sample_id_column else None)
    return _LabColumns(sample, avail, raw, dry, ids)


def _lab_results(cols: _LabColumns, lab: LabMap, where: str, where_key: str, echo: bool,
                 arrived: bool) -> list[tuple[LabResult, float]]:
    """A checked result and its moisture as written for every row with a moisture (rows
    without one are skipped); :class:`IngestError` naming the first row that breaks the
    lab-result contract, with the map key to check."""
    results: list[tuple[LabResult, float]] = []
    for i in range(len(cols.raw)):
        if np.isnan(cols.raw[i]):
            continue
        at = f"{where} row {i + 1}"
        sample, avail = int(cols.sample[i]), int(cols.avail[i])
        problem = (_moisture_problem(float(cols.raw[i]), float(cols.dry[i]), lab, where_key,
                                     echo)
                   or _time_problem(sample, avail, lab, where_key, arrived=arrived))
        if problem is not None:
            raise IngestError(f"{at}: {problem}")
        sid = cols.ids.iloc[i] if cols.ids is not None else f"lab-{iso_utc(sample)}"
        if cols.ids is not None and not sid:
            raise IngestError(f"{at}: {lab.sample_id_column} is empty")
        try:
            results.append((make_lab_result(sample, float(cols.dry[i]), sid, log_time_ns=avail,
                                            where=at), float(cols.raw[i])))
        except IngestError as exc:
            if echo:
                raise
            raise IngestError(f"{at}: not a usable lab result") from exc
    return results


__all__ = ["LabTable", "convert_labs"]
