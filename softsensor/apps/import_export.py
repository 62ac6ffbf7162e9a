"""``softsensor import`` (and, from :mod:`.estimates_export`, ``softsensor export``):
historian tables in, estimate tables out.

``import`` turns a historian export (CSV or Parquet, wide or long layout) and optionally a
LIMS file into a recorded day (CONTRACT section 2), laid out by a historian map
(:mod:`softsensor.ingest.historian_map`); the conversion is
:mod:`softsensor.ingest.historian_export` and :mod:`softsensor.ingest.lims`. Each signal is also
held against the operating envelope the estimator will apply (the plausibility limits of the plant
config, ``--config``;
:mod:`softsensor.ingest.envelope`): a signal mostly outside it is refused in one line naming
the likely right unit. ``--preview`` prints what the map makes of the export (and the LIMS
file: each result as read and as converted) and writes nothing. It prints one summary line,
its times on the map's clock.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from softsensor.apps.estimates_export import add_export_command
from softsensor.errors import ConfigError, IngestError
from softsensor.files import writing
from softsensor.ingest.envelope import (
    EnvelopeCheck,
    check_envelope,
    envelope_problem,
    lab_unit_hints,
)
from softsensor.ingest.historian_export import ScanTable
from softsensor.ingest.lims import LabTable
from softsensor.messages import iso_utc, lab_body
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN


def write_imported_day(path: str | Path, scans: ScanTable, labs: LabTable | None) -> int:
    """Write scans and lab results as a recorded day, in log-time order; messages written."""
    from softsensor.recording.day_writer import DayWriter

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


def _clock(ns: int, zone: str | None) -> str:
    """A time as the plant's clock reads it (the map's zone), or UTC."""
    if zone is None:
        return iso_utc(ns)
    from softsensor.presentation.display import DisplaySettings, local_clock

    return local_clock(ns, DisplaySettings(time_zone=zone))


def _read_scans(hmap, path: Path, strict: bool) -> ScanTable:
    from softsensor.ingest.historian_export import convert_scans
    from softsensor.ingest.tables import read_table

    src = hmap.source
    frame = read_table(path, delimiter=src.delimiter, skip_rows=src.skip_rows,
                       max_rows=src.max_rows)
    return convert_scans(frame, hmap, str(path), strict=strict)


def _read_labs(hmap, path: Path) -> LabTable:
    from softsensor.ingest.lims import convert_labs
    from softsensor.ingest.tables import read_table

    lab = hmap.lab
    assert lab is not None
    frame = read_table(path, delimiter=lab.delimiter, skip_rows=lab.skip_rows, table="lab")
    return convert_labs(frame, lab, hmap.source.time_zone, str(path))


def _aligned(rows: list[tuple[str, ...]]) -> list[str]:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
            for r in rows]


def _envelope(cfg_path: str | None, scans: ScanTable, hmap) -> dict[str, EnvelopeCheck]:
    """Every mapped signal held against the estimator's plausibility limits of the plant
    config (``--config``; the built-in one without)."""
    from softsensor.plantconfig import load_plant_config
    from softsensor.windows.plausibility import plausibility_from_config

    limits = plausibility_from_config(load_plant_config(cfg_path)).limits
    return check_envelope(scans.values, scans.raw, hmap.signals, limits)


def _lab_preview(hmap, labs: LabTable, path: Path, rows: int) -> list[str]:
    """The first lab results as the LIMS file wrote them and as converted (dry basis), and
    what looks wrong with the ``[lab]`` unit or basis."""
    lab = hmap.lab
    out = [f"lab results of {path}: {len(labs.results)} from {labs.rows_read} rows, "
           f"{lab.moisture_column!r} read as {lab.unit} on a {lab.basis} basis:"]
    table = [("sample_id", "sample time", f"as read [{lab.unit} {lab.basis}]",
              "moisture_out [kg/kg dry]", "[% wet]")]
    zone = lab.time_zone or hmap.source.time_zone
    for r, raw in list(zip(labs.results, labs.raw, strict=True))[:rows]:
        x = r.moisture_out
        table.append((r.sample_id, _clock(r.sample_time_ns, zone), f"{raw:g}", f"{x:.4f}",
                      f"{100 * x / (1 + x):.2f}"))
    out += _aligned(table)
    out += [f"SUSPECT lab unit: {h}" for h in lab_unit_hints(lab, np.asarray(labs.raw))]
    return out


def preview_text(hmap, scans: ScanTable, path: Path, rows: int,
                 envelope: dict[str, EnvelopeCheck] | None = None) -> str:
    """What ``import --preview`` prints: each signal's source, unit and range in the export's
    unit and in SI, its physical range and the estimator's envelope with the share outside
    it, the values outside the physical ranges, the signals the import would refuse (with
    the likely right unit), then the first scans (SI)."""
    from softsensor.ingest.units import PHYSICAL_RANGE
    from softsensor.signals import SCAN_SIGNALS

    envelope = envelope or {}

    zone = hmap.source.time_zone
    period, _ = scans.period_s()
    out = [f"preview of {path} (nothing written): {scans.rows_read} rows, {len(scans)} scans "
           f"{_clock(int(scans.times_ns[0]), zone)} .. {_clock(int(scans.times_ns[-1]), zone)}"
           + ("" if math.isnan(period) else f", period {period:g} s")]
    head = ("signal", "from", "unit", "min", "max", "SI unit", "SI min", "SI max",
            "physical range", "envelope", "outside", "bad", "missing")
    table = [head]

    def rng(v) -> tuple[str, str]:
        ok = v[np.isfinite(v)]
        return (f"{ok.min():.4g}", f"{ok.max():.4g}") if ok.size else ("-", "-")

    for name, si_unit in SCAN_SIGNALS.items():
        sm = hmap.signals.get(name)
        lo, hi = PHYSICAL_RANGE[name]
        if sm is None:
            table.append((name, "(not in the map)", "", "", "", si_unit, "", "",
                          f"{lo:g}..{hi:g}", "", "", "", str(len(scans))))
            continue
        unit = sm.unit + ("" if sm.quantity == "humidity_ratio" else f" ({sm.quantity})")
        env = envelope.get(name)
        env_txt = "" if env is None else f"{env.limits.low:g}..{env.limits.high:g}"
        out_txt = "" if env is None or not env.n_good else f"{env.share_outside:.0%}"
        table.append((name, sm.column or sm.tag or f"constant {sm.constant:g}", unit,
                      *rng(scans.raw[name]), si_unit, *rng(scans.values[name]),
                      f"{lo:g}..{hi:g}", env_txt, out_txt, str(scans.bad[name]),
                      str(scans.missing[name])))
    out += _aligned(table)
    out += [f"OUTSIDE: {p}" for p in scans.out_of_range]
    out += [f"SUSPECT unit, the import refuses it: "
            f"{envelope_problem(c, hmap.signals[c.name], str(path))}"
            for c in envelope.values() if c.refused]
    names = list(SCAN_SIGNALS)
    out.append(f"first {min(rows, len(scans))} scans (SI units, time UTC):")
    first = [("time_utc", *names)]
    for i in range(min(rows, len(scans))):
        body = scans.body(i)
        first.append((iso_utc(int(scans.times_ns[i])),
                      *("null" if body[n] is None else f"{body[n]:.6g}" for n in names)))
    out += _aligned(first)
    return "\n".join(out)


def _import(args: argparse.Namespace) -> int:
    from softsensor.ingest.historian_map import load_map

    hmap = load_map(args.map)
    if args.lab and hmap.lab is None:
        raise ConfigError(f"{hmap.path}: --lab given but the map has no [lab] section")
    if args.preview is not None and not 1 <= args.preview <= 10_000:
        raise ConfigError(f"--preview {args.preview}: give 1 to 10000 rows")
    if args.out is None and args.preview is None:
        raise ConfigError("import: give --out DAY.mcap (or --preview to look first)")
    scans_path = Path(args.scans)
    scans = _read_scans(hmap, scans_path, strict=args.preview is None)
    envelope = _envelope(args.config, scans, hmap)
    labs = _read_labs(hmap, Path(args.lab)) if args.lab else None
    if args.preview is not None:
        text = preview_text(hmap, scans, scans_path, args.preview, envelope)
        if labs is not None:
            text += "\n" + "\n".join(_lab_preview(hmap, labs, Path(args.lab), args.preview))
        print(text, flush=True)
        lab_txt = "" if labs is None else f", {len(labs.results)} lab results"
        print(f"import --preview: {len(scans)} scans{lab_txt} read; nothing written",
              file=sys.stderr)
        return 0
    refused = [c for c in envelope.values() if c.refused]
    if refused:
        more = (f" [{len(refused) - 1} more signals outside the envelope: softsensor import "
                f"--preview lists them]" if len(refused) > 1 else "")
        raise IngestError(envelope_problem(refused[0], hmap.signals[refused[0].name],
                                           str(scans_path)) + more)
    if labs is not None:

        for hint in lab_unit_hints(hmap.lab, np.asarray(labs.raw)):
            print(f"warning: {args.lab}: {hint}", file=sys.stderr)
    write_imported_day(args.out, scans, labs)
    zone = hmap.source.time_zone
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
          f"{_clock(int(scans.times_ns[0]), zone)} .. {_clock(int(scans.times_ns[-1]), zone)}, "
          f"{period_txt}; bad values: {_counts(scans.bad)}; missing: {_counts(scans.missing)}"
          f"{unmapped}{lab_txt}; wrote {args.out}", file=sys.stderr)
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
    p.add_argument("--out", default=None, metavar="DAY.mcap", help="MCAP file to write")
    p.add_argument("--config", default=None, metavar="PLANT.toml",
                   help="plant config whose [plausibility] limits (the estimator's operating "
                        "envelope) each signal is held against (default: built-in dryer1)")
    p.add_argument("--preview", type=int, nargs="?", const=5, default=None, metavar="ROWS",
                   help="print each signal's source, unit and range and the first ROWS (5) "
                        "converted scans, and write nothing")
    p.set_defaults(func=_import)

    add_export_command(sub)
