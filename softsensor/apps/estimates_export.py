"""``softsensor export``: the estimates of a recording as a table for a historian or a
spreadsheet.

One row per estimator tick (:mod:`softsensor.recording.estimates_table`): by default the
columns a plant reads (the moisture estimates and their standard deviations, the outlet
temperatures measured and modelled, whether a lab result was applied, the scans in the window,
the health), in SI and UTC like every file other programs read. ``--plant-units`` writes what
people read instead: moisture in % on the ``[display]`` basis of ``--config`` (wet unless set)
and temperatures in °C, each column's name saying its unit; ``--local-time`` adds the plant's
clock time beside UTC; ``--all-columns`` adds the estimator's internals (``nis``, ``clipped``,
offsets, raw model temperatures, the health's counters).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from softsensor.errors import ConfigError, IngestError
from softsensor.files import writing
from softsensor.presentation.display import (
    DisplaySettings,
    local_clock,
    moisture_pct,
    moisture_pct_points,
)

#: The columns written without ``--all-columns``, in this order (those the recording has).
PLANT_COLUMNS: tuple[str, ...] = (
    "time_utc", "time_ns", "moisture_out", "moisture_out_std", "moisture_in",
    "moisture_in_std", "T_dryer_out_measured", "T_dryer_out_model", "T_cyclone_out_measured",
    "T_cyclone_out_model", "lab_updated", "n_scans", "health_status",
)
_MOISTURE = ("moisture_out", "moisture_in")
_TEMPERATURES = ("T_dryer_out_measured", "T_dryer_out_model", "T_cyclone_out_measured",
                 "T_cyclone_out_model")


def _display(config: str | None) -> DisplaySettings:
    from softsensor.plantconfig import load_plant_config
    from softsensor.presentation.display import display_settings

    return display_settings(load_plant_config(config)) if config else DisplaySettings()


def export_table(table: pd.DataFrame, display: DisplaySettings, *, plant_units: bool = False,
                 local_time: bool = False, all_columns: bool = False) -> pd.DataFrame:
    """The columns of an estimates table that ``export`` writes (module docstring)."""
    out = table.copy() if all_columns else table[[c for c in PLANT_COLUMNS if c in table]]
    if local_time:
        local = [local_clock(int(t), display) for t in table["time_ns"]]
        out.insert(1, "time_local", local)
    if plant_units:
        basis = display.moisture_basis
        tag = f"{basis[0]}b_pct"
        renames = {}
        for key in _MOISTURE:
            if key not in out:
                continue
            x = out[key].astype(float).to_numpy()
            out[key] = moisture_pct(x, basis)
            renames[key] = f"{key}_{tag}"
            std = f"{key}_std"
            if std in out:
                sd = out[std].astype(float).to_numpy()
                out[std] = [moisture_pct_points(s, v, basis) if np.isfinite(v) else np.nan
                            for s, v in zip(sd, x, strict=True)]
                renames[std] = f"{std}_{tag}"
        for key in _TEMPERATURES:
            if key in out:
                out[key] = out[key].astype(float) - 273.15
                renames[key] = f"{key}_degC"
        out = out.rename(columns=renames)
    return out.reset_index(drop=True)


def _export(args: argparse.Namespace) -> int:
    from softsensor.ingest.tables import table_kind, write_table
    from softsensor.recording.estimates_table import estimates_table

    targets = [(p, kind) for p, kind in ((args.csv, "csv"), (args.parquet, "parquet")) if p]
    if not targets:
        raise ConfigError("export: give --csv OUT.csv and/or --parquet OUT.parquet")
    for p, kind in targets:
        if table_kind(Path(p)) != kind:
            raise IngestError(f"--{kind} {p}: the file name does not end in .{kind}")
    display = _display(args.config)
    table = export_table(estimates_table(args.recording), display,
                         plant_units=args.plant_units, local_time=args.local_time,
                         all_columns=args.all_columns)
    for p, kind in targets:
        with writing(p, f"--{kind}") as tmp:
            write_table(table, tmp)
    first, last = (local_clock(int(t), display) for t in (table["time_ns"].iloc[0],
                                                           table["time_ns"].iloc[-1]))
    print(f"exported {args.recording}: {len(table)} estimates {first} .. {last}, "
          f"{table.shape[1]} columns; wrote {', '.join(p for p, _ in targets)}", file=sys.stderr)
    return 0


def add_export_command(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("export", help="estimates of a recording -> CSV/Parquet table",
                       description="One row per estimate: time_utc, time_ns, the estimates, "
                                   "the outlet temperatures measured and modelled, the health "
                                   "(SI and UTC unless asked otherwise).")
    e.add_argument("recording", metavar="EST.mcap", help="replay or daemon recording")
    e.add_argument("--csv", default=None, metavar="OUT.csv", help="CSV file to write")
    e.add_argument("--parquet", default=None, metavar="OUT.parquet",
                   help="Parquet file to write")
    e.add_argument("--config", default=None,
                   help="plant config whose [display] table sets the time zone and the "
                        "moisture basis (default: built-in dryer1: UTC, wet)")
    e.add_argument("--local-time", action="store_true",
                   help="add time_local: the plant's clock time, with its offset")
    e.add_argument("--plant-units", action="store_true",
                   help="moisture in %% on the [display] basis, temperatures in °C")
    e.add_argument("--all-columns", action="store_true",
                   help="also the estimator's internals (nis, clipped, offsets, counters)")
    e.set_defaults(func=_export)


__all__ = ["PLANT_COLUMNS", "add_export_command", "export_table"]
