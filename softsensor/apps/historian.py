"""``softsensor import`` and ``softsensor export``: historian tables in, estimate tables out.

``import`` turns a historian export (CSV or Parquet, wide or long layout) and optionally a
LIMS file into a recorded day (CONTRACT section 2), laid out by a historian map
(:mod:`softsensor.ingest.historian_map`); the conversion is :mod:`softsensor.ingest.historian`.
``export`` writes the estimates (and health) of a replay or daemon recording as a CSV or
Parquet table (:mod:`softsensor.recording.estimates_table`). Both print one summary line.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from softsensor.apps.output import writing
from softsensor.errors import ConfigError, IngestError
from softsensor.ingest.historian import LabTable, ScanTable
from softsensor.messages import iso_utc, lab_body
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN


def write_imported_day(path: str | Path, scans: ScanTable, labs: LabTable | None) -> int:
    """Write scans and lab results as a recorded day, in log-time order; messages written."""
    from softsensor.recording.mcap_day import DayWriter

    pending = labs.results if labs is not None else []
    j = 0
    out = Path(path)
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    with writing(out) as tmp, DayWriter(tmp) as w:
        for i, t in enumerate(scans.times_ns.tolist()):
            while j < len(pending) and pending[j].log_time_ns <= t:
                w.write(TOPIC_LAB, pending[j].log_time_ns, lab_body(pending[j]))
                j += 1
            w.write(TOPIC_SCAN, t, scans.body(i))
        for lab in pending[j:]:
            w.write(TOPIC_LAB, lab.log_time_ns, lab_body(lab))
    return w.n_messages


def _counts(counts: dict[str, int]) -> str:
    parts = [f"{k} {v}" for k, v in counts.items() if v]
    return ", ".join(parts) if parts else "none"


def _import(args: argparse.Namespace) -> int:
    from softsensor.ingest.historian import convert_labs, convert_scans
    from softsensor.ingest.historian_map import load_map
    from softsensor.ingest.tables import read_table

    hmap = load_map(args.map)
    if args.lab and hmap.lab is None:
        raise ConfigError(f"{hmap.path}: --lab given but the map has no [lab] section")
    scans_path = Path(args.scans)
    scans = convert_scans(read_table(scans_path, delimiter=hmap.source.delimiter), hmap,
                          str(scans_path))
    labs = None
    if args.lab:
        assert hmap.lab is not None
        lab_path = Path(args.lab)
        labs = convert_labs(read_table(lab_path, delimiter=hmap.lab.delimiter), hmap.lab,
                            hmap.source.time_zone, str(lab_path))
    write_imported_day(args.out, scans, labs)
    period, regular = scans.period_s()
    period_txt = ("period n/a (one scan)" if math.isnan(period)
                  else f"period {period:g} s ({'regular' if regular else 'irregular'})")
    skipped = f", {scans.skipped_rows} rows of unmapped tags skipped" if scans.skipped_rows else ""
    unmapped = f"; not in the map (null): {', '.join(hmap.unmapped)}" if hmap.unmapped else ""
    lab_txt = ""
    if labs is not None:
        lab_txt = (f"; {len(labs.results)} labs written from {labs.rows_read} rows"
                   + (f" ({labs.bad} without a result)" if labs.bad else ""))
    print(f"imported {scans_path}: {scans.rows_read} rows read{skipped}, {len(scans)} scans "
          f"{iso_utc(int(scans.times_ns[0]))} .. {iso_utc(int(scans.times_ns[-1]))}, "
          f"{period_txt}; bad values: {_counts(scans.bad)}; missing: {_counts(scans.missing)}"
          f"{unmapped}{lab_txt}; wrote {args.out}", file=sys.stderr)
    return 0


def _export(args: argparse.Namespace) -> int:
    from softsensor.ingest.tables import table_kind, write_table
    from softsensor.recording.estimates_table import estimates_table

    targets = [(p, kind) for p, kind in ((args.csv, "csv"), (args.parquet, "parquet")) if p]
    if not targets:
        raise ConfigError("export: give --csv OUT.csv and/or --parquet OUT.parquet")
    for p, kind in targets:
        if table_kind(Path(p)) != kind:
            raise IngestError(f"--{kind} {p}: the file name does not end in .{kind}")
    table = estimates_table(args.recording)
    for p, kind in targets:
        with writing(p, f"--{kind}") as tmp:
            write_table(table, tmp)
    print(f"exported {args.recording}: {len(table)} estimates "
          f"{table['time_utc'].iloc[0]} .. {table['time_utc'].iloc[-1]}, "
          f"{table.shape[1]} columns; wrote {', '.join(p for p, _ in targets)}", file=sys.stderr)
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("import", help="historian export (CSV/Parquet) and LIMS file -> MCAP day",
                       description="Convert a historian export and a LIMS file into a "
                                   "recorded day (CONTRACT section 2), laid out by a map "
                                   "(example: replay/historian-map.toml).")
    p.add_argument("--map", required=True, metavar="MAP.toml",
                   help="historian map: columns or tags, units, time zone, lab convention")
    p.add_argument("--scans", required=True, metavar="EXPORT",
                   help="historian export, .csv or .parquet (wide or long layout)")
    p.add_argument("--lab", default=None, metavar="LIMS",
                   help="LIMS file, .csv or .parquet (needs the map's [lab] section)")
    p.add_argument("--out", required=True, metavar="DAY.mcap", help="MCAP file to write")
    p.set_defaults(func=_import)

    e = sub.add_parser("export", help="estimates of a recording -> CSV/Parquet table",
                       description="One row per estimate: time_utc, time_ns, every numeric "
                                   "estimate field, the health at that time (health_*).")
    e.add_argument("recording", metavar="EST.mcap", help="replay or daemon recording")
    e.add_argument("--csv", default=None, metavar="OUT.csv", help="CSV file to write")
    e.add_argument("--parquet", default=None, metavar="OUT.parquet",
                   help="Parquet file to write")
    e.set_defaults(func=_export)
