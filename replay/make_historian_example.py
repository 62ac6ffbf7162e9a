"""Write the historian example from the demo day, so it describes a day whose truth we know.

    python replay/make_historian_example.py            # from the repository root

reads ``replay/demo-day.mcap`` (CONTRACT section 2, SI units, UTC) and writes, next to it:

* ``historian-example.csv``: the first 12 hours of the day's scans as a plant historian exports
  them: one row per minute (the scan at each whole minute, no averaging), one column per tag
  (wide layout), local time Europe/Stockholm without an offset, temperatures in °C, air and
  fibre flows in t/h, steam in kg/h, ambient humidity in g/kg, flaps in %; a few cells hold the
  historian's bad-value strings (``Bad``, ``I/O Timeout``, ``Shutdown``) instead of a number;
* ``lims-example.csv``: the day's lab results of those hours as a LIMS exports them: sample
  and result times in local time, moisture in % on a wet basis (w = X / (1 + X));
* ``historian-map.toml``: the map ``softsensor import`` needs to read both back.

The unit conversions here are written out by hand on purpose: ``softsensor import`` converts
with pint, so the round trip compares two independent conversions.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pandas as pd

from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN

HERE = Path(__file__).resolve().parent
ZONE = "Europe/Stockholm"
HOURS = 12
#: Cells replaced by bad-value strings: (minute of the export, signal, string).
BAD_CELLS: tuple[tuple[int, str, str], ...] = (
    (95, "T_air_in", "Bad"), (96, "T_air_in", "Bad"), (301, "m_fiber", "I/O Timeout"),
    (460, "T_cyclone_out", "Bad"), (610, "H_amb", "Shutdown"),
)

#: signal -> (tag, unit written in the map, SI -> plant unit, decimals printed)
TAGS: dict[str, tuple[str, str, object, int]] = {
    "T_air_in": ("DRY1_TI101.PV", "degC", lambda k: k - 273.15, 2),
    "m_air": ("DRY1_FI102.PV", "t/h", lambda q: q * 3.6, 3),
    "m_fiber": ("DRY1_WI103.PV", "t/h", lambda q: q * 3.6, 4),
    "T_fiber_in": ("DRY1_TI104.PV", "degC", lambda k: k - 273.15, 2),
    "m_steam": ("DRY1_FI105.PV", "kg/h", lambda q: q * 3600.0, 2),
    "T_amb": ("SITE_TI001.PV", "degC", lambda k: k - 273.15, 2),
    "H_amb": ("SITE_MI002.PV", "g/kg", lambda h: h * 1000.0, 4),
    "flap_cmd": ("DRY1_TIC110.OP", "%", lambda p: p, 3),
    "T_sp": ("DRY1_TIC110.SP", "degC", lambda k: k - 273.15, 2),
    "T_dryer_out": ("DRY1_TIC110.PV", "degC", lambda k: k - 273.15, 2),
    "T_cyclone_out": ("DRY1_TI111.PV", "degC", lambda k: k - 273.15, 2),
}

MAP = f"""# Historian map of replay/historian-example.csv and replay/lims-example.csv
# (written by replay/make_historian_example.py). Import with
#   softsensor import --map replay/historian-map.toml --scans replay/historian-example.csv \\
#       --lab replay/lims-example.csv --out historian-day.mcap

[source]
layout = "wide"
time_column = "Timestamp"
time_zone = "{ZONE}"   # the export's times are local, without an offset

""" + "\n".join(f'[signals.{name}]\ncolumn = "{tag}"\nunit = "{unit}"\n'
                for name, (tag, unit, _f, _d) in TAGS.items()) + """
[lab]
sample_time_column = "SampleTime"
available_column = "ResultTime"
moisture_column = "Moisture_wb_pct"
sample_id_column = "SampleID"
unit = "%"
basis = "wet"
"""


def _local(ns: np.ndarray) -> pd.Index:
    return pd.to_datetime(ns, unit="ns", utc=True).tz_convert(ZONE).strftime("%Y-%m-%d %H:%M:%S")


def main() -> None:
    day = read_day(HERE / "demo-day.mcap", topics=[TOPIC_SCAN, TOPIC_LAB])
    start = day.start_ns
    end = start + HOURS * 3600 * 10**9
    minute = 60 * 10**9
    scans = day.scans[(day.scans.index < end) & ((day.scans.index - start) % minute == 0)]
    bad = {(m, s): text for m, s, text in BAD_CELLS}
    with (HERE / "historian-example.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["Timestamp", *(tag for tag, _u, _f, _d in TAGS.values())])
        for m, (stamp, row) in enumerate(zip(_local(scans.index.to_numpy()),
                                             scans.itertuples(index=False), strict=True)):
            values = row._asdict()
            w.writerow([stamp, *(bad.get((m, s), f"{conv(values[s]):.{dec}f}")
                                 for s, (_t, _u, conv, dec) in TAGS.items())])
    labs = day.labs[day.labs.log_time_ns < end]
    with (HERE / "lims-example.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["SampleID", "SampleTime", "ResultTime", "Moisture_wb_pct"])
        for sid, st, lt, x in zip(labs.sample_id, _local(labs.sample_time_ns.to_numpy()),
                                  _local(labs.log_time_ns.to_numpy()), labs.moisture_out,
                                  strict=True):
            w.writerow([sid, st, lt, f"{100.0 * x / (1.0 + x):.3f}"])
    (HERE / "historian-map.toml").write_text(MAP, encoding="utf-8")
    print(f"wrote {len(scans)} rows of historian-example.csv, {len(labs)} of lims-example.csv, "
          "historian-map.toml")


if __name__ == "__main__":
    main()
