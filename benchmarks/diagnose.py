"""Benchmark of ``softsensor diagnose``: wall time of a 48 h day with calibration, and accuracy.

1. Wall time: the virtual plant records a clean calibration day and a day hiding an effect
   (both ``--hours``, 48 h by default) as MCAP files; ``softsensor diagnose --calibrate-on
   CAL.mcap DAY.mcap --json REPORT.json`` runs in this process and is timed end to end
   (reading both files, the calibration with ``--trials`` Optuna trials plus the polish, the
   diagnosis). Target: at most 5 minutes on this machine.
2. Accuracy: ``--cases`` days of ``--case-hours`` each, cycling through every cause and clean
   days, with magnitudes drawn uniformly from each effect's detectable range, diagnosed with
   the config step 1 saved (its parameters and ``[discrepancy]``, as ``--params`` reads
   it). A case is right when the named cause (and for ``sensor_bias`` the channel) is the
   hidden one; each case keeps the named cause's probability and the "cannot tell" pair,
   counted apart in the summary.

This is the matched plant (the model itself): the floor beside the open-world numbers of
``benchmarks/open_world.py``. The plant's true parameters are the config's (``--truth
config``) or a set away from them (``--truth shifted``, the calibration benchmark's), so that
the calibration has to find them.
``--cases-with truth`` diagnoses the accuracy cases with the plant's true parameters instead
(the per-cause tests' setting: what the diagnosis does when the model is right, apart from
the hidden effect). Prints one JSON document; the load average is included because the
machine is shared.

    python benchmarks/diagnose.py [--hours 48] [--trials 40] [--cases 14] [--case-hours 30]
                                  [--truth shifted] [--cases-with calibrated] [--seed 0]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from softsensor.cli import main as cli_main
from softsensor.diagnosis.diagnose_day import diagnose
from softsensor.plant.effects import EFFECTS
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_parameters, load_plant_config

SHIFTED = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
           "hm_cyc": 3e-4, "hc_cyc": 50.0}
CASES = ("none", *EFFECTS)


def _magnitude(cause: str, seed: int) -> float | None:
    if cause == "none":
        return None
    lo, hi = EFFECTS[cause].detectable
    return float(np.random.default_rng([seed, 7]).uniform(lo, hi))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=48.0, help="CAL and DAY length [h]")
    ap.add_argument("--trials", type=int, default=40, help="calibration trials")
    ap.add_argument("--effect", default="inlet_moisture", help="effect hidden in the timed day")
    ap.add_argument("--cases", type=int, default=14, help="randomised accuracy cases")
    ap.add_argument("--case-hours", type=float, default=30.0, help="length of a case [h]")
    ap.add_argument("--truth", choices=("config", "shifted"), default="shifted")
    ap.add_argument("--cases-with", choices=("calibrated", "truth"), default="calibrated",
                    help="parameters the accuracy cases are diagnosed with")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    cfg = load_plant_config()
    plant = cfg.with_parameters(SHIFTED) if args.truth == "shifted" else cfg
    out: dict = {"hours": args.hours, "trials": args.trials, "truth": args.truth,
                 "seed": args.seed, "target_s": 300.0}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        cal = simulate_day(plant, args.hours, args.seed).write(d / "cal.mcap")
        mag = _magnitude(args.effect, args.seed + 1)
        day = simulate_day(plant, args.hours, args.seed + 1, args.effect, mag)
        path = day.write(d / "day.mcap")
        report, params = d / "report.json", d / "params.toml"
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli_main(["diagnose", "--calibrate-on", str(cal), str(path), "--json",
                           str(report), "--trials", str(args.trials), "--window-hours",
                           str(args.hours), "--save-params", str(params)])
        wall = time.perf_counter() - t0
        rep = json.loads(report.read_text())
        cal_cfg = load_parameters(params, cfg)
        cal_rmse = rep["calibration"]["rmse"]
    out.update({
        "exit_code": rc, "wall_time_s": round(wall, 1), "within_target": wall <= 300.0,
        "calibration_s": rep["calibration"]["seconds"],
        "diagnosis_s": rep["timings_s"].get("total"),
        "timed_day": {"effect": args.effect, "magnitude": mag,
                      "channel": day.effect.get("channel"), "named": rep["cause"],
                      "named_channel": rep["channel"], "gain": rep["gain"]},
        "calibrated_params": rep["calibration"]["params"],
        "calibration_rmse": cal_rmse,
    })
    if args.cases_with == "truth":
        cal_cfg, cal_rmse = plant, None
    out["cases_with"] = args.cases_with
    cases = []
    t1 = time.perf_counter()
    for i in range(args.cases):
        cause = CASES[i % len(CASES)]
        seed = args.seed + 100 + i
        m = _magnitude(cause, seed)
        day = simulate_day(plant, args.case_hours, seed, None if cause == "none" else cause, m)
        rep = diagnose(cal_cfg, day).to_json()
        right = rep["cause"] == cause and (cause != "sensor_bias"
                                           or rep["channel"] == day.effect.get("channel"))
        cases.append({"seed": seed, "cause": cause, "magnitude": m, "named": rep["cause"],
                      "channel": rep["channel"], "gain": rep["gain"], "right": right,
                      "probability": rep["probabilities"][0]["probability"],
                      "cannot_tell": [c["cause"] for c in rep["cannot_tell"]]})
    n_right = sum(c["right"] for c in cases)
    out.update({
        "cases": cases, "n_cases": len(cases), "accuracy": n_right / max(len(cases), 1),
        "false_alarms": sum(c["cause"] == "none" and c["named"] != "none" for c in cases),
        "missed": sum(c["cause"] != "none" and c["named"] == "none" for c in cases),
        "positive_gain_share": (sum(c["gain"] > 0 for c in cases if c["cause"] != "none")
                                / max(sum(c["cause"] != "none" for c in cases), 1)),
        # issue 39: "cannot tell" counted apart, and how sure the wrong verdicts were
        "cannot_tell_days": sum(bool(c["cannot_tell"]) for c in cases),
        "true_in_cannot_tell_pair": sum(c["cause"] in c["cannot_tell"] for c in cases),
        "wrong_above_0.9": sum(not c["right"] and c["probability"] > 0.9 for c in cases),
        "smallest_gain_named_right": min([c["gain"] for c in cases
                                          if c["right"] and c["cause"] != "none"], default=None),
        "seconds_per_case": round((time.perf_counter() - t1) / max(len(cases), 1), 1),
        "load_average": list(os.getloadavg()),
    })
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
