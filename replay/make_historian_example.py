"""Write the historian example from the demo day, so it describes a day whose truth we know.

    python replay/make_historian_example.py            # from the repository root

reads ``replay/demo-day.mcap`` (CONTRACT section 2, SI units, UTC) and writes, next to it:

* ``historian-example.csv``: the first 12 hours of the day's scans as an OSIsoft PI (or IP.21)
  export written for a Spanish plant: one row per minute (the scan at each whole minute, no
  averaging), one column per tag named like ``TI-4711.PV`` (wide layout), a row of units under
  the header, local time Europe/Madrid without an offset written ``dd/mm/yyyy hh:mm:ss``,
  temperatures in °C, air and fibre flows in t/h, steam in kg/h, ambient humidity as relative
  humidity in %, flaps in %; a few cells hold the historian's bad-value strings
  (``Bad Value``, ``I/O Timeout``, ``Shutdown``) instead of a number;
* ``lims-example.csv``: the day's lab results of those hours as a LIMS exports them: sample
  and result times in local time (day first), moisture in % on a wet basis (w = X / (1 + X));
* ``historian-map.toml``: the map ``softsensor import`` needs to read both back.

The conversions here are written out by hand on purpose, the relative humidity by psychrolib
(ASHRAE 2017, a test dependency): ``softsensor import`` converts with pint and the model's
own psychrometrics, so the round trip compares two independent conversions.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pandas as pd
import psychrolib

from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_LAB, TOPIC_SCAN

HERE = Path(__file__).resolve().parent
ZONE = "Europe/Madrid"
HOURS = 12
#: Ambient pressure of the relative humidity, as the map states it [Pa].
PRESSURE_PA = 101_325.0
#: Cells replaced by bad-value strings: (minute of the export, signal, string).
BAD_CELLS: tuple[tuple[int, str, str], ...] = (
    (95, "T_air_in", "Bad Value"), (96, "T_air_in", "Bad Value"),
    (301, "m_fiber", "I/O Timeout"), (460, "T_cyclone_out", "Bad Value"),
    (610, "H_amb", "Shutdown"),
)
psychrolib.SetUnitSystem(psychrolib.SI)


def _rh_percent(values: dict) -> float:
    """Relative humidity [%] of the scan's ambient air (psychrolib, an outside reference)."""
    return 100.0 * psychrolib.GetRelHumFromHumRatio(values["T_amb"] - 273.15,
                                                    values["H_amb"], PRESSURE_PA)


#: signal -> (tag, unit written in the map, unit row text, scan -> plant unit, decimals)
TAGS: dict[str, tuple[str, str, str, object, int]] = {
    "T_air_in": ("TI-4711.PV", "degC", "°C", lambda v: v["T_air_in"] - 273.15, 2),
    "m_air": ("FI-4712.PV", "t/h", "t/h", lambda v: v["m_air"] * 3.6, 3),
    "m_fiber": ("WI-4713.PV", "t/h", "t/h", lambda v: v["m_fiber"] * 3.6, 4),
    "T_fiber_in": ("TI-4714.PV", "degC", "°C", lambda v: v["T_fiber_in"] - 273.15, 2),
    "m_steam": ("FI-4715.PV", "kg/h", "kg/h", lambda v: v["m_steam"] * 3600.0, 2),
    "T_amb": ("TI-4701.PV", "degC", "°C", lambda v: v["T_amb"] - 273.15, 2),
    "H_amb": ("MI-4702.PV", "%", "%HR", _rh_percent, 2),
    "flap_cmd": ("TIC-4720.OP", "%", "%", lambda v: v["flap_cmd"], 3),
    "T_sp": ("TIC-4720.SP", "degC", "°C", lambda v: v["T_sp"] - 273.15, 2),
    "T_dryer_out": ("TIC-4720.PV", "degC", "°C", lambda v: v["T_dryer_out"] - 273.15, 2),
    "T_cyclone_out": ("TI-4721.PV", "degC", "°C", lambda v: v["T_cyclone_out"] - 273.15, 2),
}

MAP = f"""# Historian map of replay/historian-example.csv and replay/lims-example.csv
# (written by replay/make_historian_example.py; every key: docs/historian-map.md). Look first,
# then import:
#   softsensor import --map replay/historian-map.toml --scans replay/historian-example.csv \\
#       --preview
#   softsensor import --map replay/historian-map.toml --scans replay/historian-example.csv \\
#       --lab replay/lims-example.csv --out historian-day.mcap

[source]
layout = "wide"
time_column = "Timestamp"
time_zone = "{ZONE}"   # the export's times are local, without an offset
dayfirst = true                # 07/01/2026 is 7 January
skip_rows = 1                  # the row of units under the tag names

""" + "\n".join(f'[signals.{name}]\ncolumn = "{tag}"\nunit = "{unit}"\n'
                + ('quantity = "relative_humidity"   # with T_amb of the same row\n'
                   'pressure = "1013.25 hPa"\n' if name == "H_amb" else "")
                for name, (tag, unit, _r, _f, _d) in TAGS.items()) + """
[lab]
sample_time_column = "Sample Time"
available_column = "Result Time"
moisture_column = "Moisture"
sample_id_column = "Sample ID"
unit = "%"
basis = "wet"
dayfirst = true
"""


def _local(ns: np.ndarray) -> pd.Index:
    return pd.to_datetime(ns, unit="ns", utc=True).tz_convert(ZONE).strftime("%d/%m/%Y %H:%M:%S")


def main() -> None:
    day = read_day(HERE / "demo-day.mcap", topics=[TOPIC_SCAN, TOPIC_LAB])
    start = day.start_ns
    end = start + HOURS * 3600 * 10**9
    minute = 60 * 10**9
    scans = day.scans[(day.scans.index < end) & ((day.scans.index - start) % minute == 0)]
    bad = {(m, s): text for m, s, text in BAD_CELLS}
    with (HERE / "historian-example.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["Timestamp", *(tag for tag, *_ in TAGS.values())])
        w.writerow(["", *(units for _t, _u, units, _f, _d in TAGS.values())])
        for m, (stamp, row) in enumerate(zip(_local(scans.index.to_numpy()),
                                             scans.itertuples(index=False), strict=True)):
            values = row._asdict()
            w.writerow([stamp, *(bad.get((m, s), f"{conv(values):.{dec}f}")
                                 for s, (_t, _u, _r, conv, dec) in TAGS.items())])
    labs = day.labs[day.labs.log_time_ns < end]
    with (HERE / "lims-example.csv").open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["Sample ID", "Sample Time", "Result Time", "Moisture"])
        for sid, st, lt, x in zip(labs.sample_id, _local(labs.sample_time_ns.to_numpy()),
                                  _local(labs.log_time_ns.to_numpy()), labs.moisture_out,
                                  strict=True):
            w.writerow([sid, st, lt, f"{100.0 * x / (1.0 + x):.3f}"])
    (HERE / "historian-map.toml").write_text(MAP, encoding="utf-8")
    print(f"wrote {len(scans)} rows of historian-example.csv, {len(labs)} of lims-example.csv, "
          "historian-map.toml")


if __name__ == "__main__":
    main()
