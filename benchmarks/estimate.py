"""Benchmark of the virtual sensor: seconds per tick and per 48 h day, and its accuracy.

Runs the UKF (and the open-loop estimator, for the accuracy ratio) over virtual-plant days with
the ``inlet_moisture`` effect, or over recorded days given with ``--day``, handing each lab
result over at its log time as the estimator service does. Prints one JSON document:

* ``median_s_per_tick``, ``p99_s_per_tick`` (target: median <= 0.05 s), ``day_48h_s`` (the
  UKF's time for 288 ticks, scaled from the day's ticks), ``load_average`` (shared machine);
* per day: RMSE of ``moisture_out`` against the truth averaged over each tick's window and
  against the truth at the tick, the open-loop RMSE and the ratio, RMSE of ``moisture_in``
  after the first lab, the share of ticks whose 95 % interval holds the truth (window truth
  with ``moisture_out_window_std``, tick truth with ``moisture_out_std``, ``moisture_in``), and
  the share of ticks with health ``degraded``;
* ``pooled``: the same over all days.

    python benchmarks/estimate.py [--seeds 1,2,3] [--hours 48] [--magnitude 0.15]
    python benchmarks/estimate.py --day DAY.mcap [--day DAY2.mcap]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from softsensor.estimation.interface import LabResult
from softsensor.estimation.open_loop_estimator import OpenLoopEstimator
from softsensor.estimation.ukf import UkfEstimator
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.windows.accumulator import windows_from_frame


def run(est, scans, labs_frame, truth):
    """Tick ``est`` over a day; returns per-tick rows and per-tick seconds."""
    windows = windows_from_frame(scans)
    labs = sorted((LabResult(int(r.sample_time_ns), float(r.moisture_out), str(r.sample_id),
                             int(r.log_time_ns)) for r in labs_frame.itertuples(index=False)),
                  key=lambda r: r.log_time_ns)
    t = truth.index.to_numpy() if truth is not None else None
    rows, seconds, j = [], [], 0
    for w in windows:
        t0 = time.perf_counter()
        while j < len(labs) and labs[j].log_time_ns <= w.end_ns:
            est.add_lab(labs[j])
            j += 1
        body = est.tick(w).to_body()
        seconds.append(time.perf_counter() - t0)
        row = {"end": w.end_ns, "mo": body["moisture_out"], "mo_sd": body["moisture_out_std"],
               "mo_wsd": body.get("moisture_out_window_std", np.nan), "mi": body["moisture_in"],
               "mi_sd": body["moisture_in_std"], "degraded": body["status"] == "degraded"}
        if t is not None:
            sel = (t > w.start_ns) & (t <= w.end_ns)
            if sel.any():
                tr = truth[sel]
                row.update(mo_mean=tr.moisture_out.mean(), mo_now=tr.moisture_out.iloc[-1],
                           mi_now=tr.moisture_in.iloc[-1])
        rows.append(row)
    return rows, np.array(seconds)


def _col(rows, key):
    return np.array([r.get(key, np.nan) for r in rows], float)


def score(ukf_rows, ol_rows, first_lab_ns):
    """Accuracy of one day (see the module docstring)."""
    ok = ~np.isnan(_col(ukf_rows, "mo_now")) & ~np.isnan(_col(ukf_rows, "mo"))
    mo, mi = _col(ukf_rows, "mo")[ok], _col(ukf_rows, "mi")[ok]
    mo_mean, mo_now = _col(ukf_rows, "mo_mean")[ok], _col(ukf_rows, "mo_now")[ok]
    mi_now = _col(ukf_rows, "mi_now")[ok]
    after = _col(ukf_rows, "end")[ok] >= first_lab_ns
    ol_ok = ~np.isnan(_col(ol_rows, "mo")) & ~np.isnan(_col(ol_rows, "mo_now"))
    ol = float(np.sqrt(np.mean((_col(ol_rows, "mo") - _col(ol_rows, "mo_now"))[ol_ok] ** 2)))
    rm = float(np.sqrt(np.mean((mo - mo_now) ** 2)))
    return {
        "moisture_out_rmse_window": float(np.sqrt(np.mean((mo - mo_mean) ** 2))),
        "moisture_out_rmse_tick": rm,
        "openloop_moisture_out_rmse_tick": ol,
        "ratio_to_openloop": rm / ol,
        "moisture_in_rmse_after_first_lab": float(np.sqrt(np.mean((mi - mi_now)[after] ** 2))),
        "cover95_moisture_out_window": float(np.mean(np.abs(mo - mo_mean)
                                                     <= 1.96 * _col(ukf_rows, "mo_wsd")[ok])),
        "cover95_moisture_out_tick": float(np.mean(np.abs(mo - mo_now)
                                                   <= 1.96 * _col(ukf_rows, "mo_sd")[ok])),
        "cover95_moisture_in": float(np.mean(np.abs(mi - mi_now)
                                             <= 1.96 * _col(ukf_rows, "mi_sd")[ok])),
        "degraded_share": float(np.mean(_col(ukf_rows, "degraded")[ok])),
        "ticks": int(ok.sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--hours", type=float, default=48.0)
    ap.add_argument("--magnitude", type=float, default=None)
    ap.add_argument("--day", action="append", default=[], help="recorded MCAP day(s)")
    args = ap.parse_args()
    cfg = load_plant_config()
    days = []
    if args.day:
        for path in args.day:
            d = read_day(path)
            days.append((path, d.scans, d.labs, d.truth))
    else:
        for seed in (int(s) for s in args.seeds.split(",")):
            d = simulate_day(cfg, args.hours, seed, effect="inlet_moisture",
                             magnitude=args.magnitude)
            days.append((f"seed {seed}", d.scans, d.labs, d.truth))
    warm = UkfEstimator(cfg)                       # numba kernels load from the disk cache
    run(warm, days[0][1].iloc[:120], days[0][2].iloc[:0], None)
    per_day, all_seconds, all_rows = {}, [], ([], [])
    for name, scans, labs, truth in days:
        ukf_rows, seconds = run(UkfEstimator(cfg), scans, labs, truth)
        all_seconds.append(seconds)
        if truth is not None:
            ol_rows, _ = run(OpenLoopEstimator(cfg), scans, labs, truth)
            first = int(labs.log_time_ns.min()) if len(labs) else np.iinfo(np.int64).max
            per_day[name] = score(ukf_rows, ol_rows, first)
            all_rows[0].extend(ukf_rows)
            all_rows[1].extend(ol_rows)
    sec = np.concatenate(all_seconds)
    out = {
        "estimator": "ukf",
        "median_s_per_tick": float(np.median(sec)),
        "p99_s_per_tick": float(np.percentile(sec, 99)),
        "day_48h_s": float(np.mean(sec) * 288),
        "ticks": int(sec.size),
        "load_average": os.getloadavg()[0],
        "days": per_day,
    }
    if len(per_day) > 1:
        out["pooled"] = score(*all_rows, first_lab_ns=-1)
        out["pooled"].pop("moisture_in_rmse_after_first_lab")
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
