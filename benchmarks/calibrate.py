"""Benchmark of ``softsensor calibrate``: 200 TPE trials on a 48 h virtual-plant day.

Prints one JSON document: wall time of the study (the paper needed 4.2 h on an i9
workstation for 200 trials), share of trials pruned, the trial at which TPE's best cost was
reached, the polish and its cost against the cost at the true parameters, the load average
(the machine is shared), and with ``--compare`` the time per trial of the ways to spend the
two cores:

* ``sequential``: one process, one trial at a time (the default of ``calibrate``);
* ``batch8``: one process, 8 trials asked at once and simulated through one batched model
  call per chunk (``--batch 8``);
* ``workers2``: two processes on one journal file (``--storage``), one trial at a time each;
* ``threads2``: Optuna's ``n_jobs=2`` (threads) on the same objective, to show whether the
  compiled model releases the GIL.

    python benchmarks/calibrate.py [--trials 200] [--hours 48] [--compare] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import optuna

from softsensor.calibration.chunked_run import ChunkedRun, simulate_segments
from softsensor.calibration.cost import evaluate_fit
from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.optimize import StudySettings, search_space, theta_of
from softsensor.calibration.pipeline import calibrate
from softsensor.model import DryerModel
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import PARAMETER_NAMES, load_plant_config

TRUTH = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
         "hm_cyc": 3e-4, "hc_cyc": 50.0}


def _time_threads(model, seg, config, n_trials: int, seed: int) -> float:
    """Seconds per trial with ``study.optimize(n_jobs=2)`` (no pruning: the same work)."""
    space = search_space(config)

    def objective(trial: optuna.Trial) -> float:
        theta = theta_of({n: trial.suggest_float(n, d.low, d.high, log=d.log)
                          for n, d in space.items()})
        return ChunkedRun(model, [seg], theta[None], config.cost.weights(), 1).run()[0].cost

    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    t0 = time.perf_counter()
    study.optimize(objective, n_trials=n_trials, n_jobs=2)
    return (time.perf_counter() - t0) / n_trials


def _time_sequential_no_prune(model, seg, config, n_trials: int, seed: int) -> float:
    space = search_space(config)
    rng = np.random.default_rng(seed)
    lo = np.log([space[n].low for n in PARAMETER_NAMES])
    hi = np.log([space[n].high for n in PARAMETER_NAMES])
    t0 = time.perf_counter()
    for _ in range(n_trials):
        theta = np.exp(rng.uniform(lo, hi))
        simulate_segments(model, [seg], theta)
    return (time.perf_counter() - t0) / n_trials


def _time_workers(day_path: Path, n_trials: int, seed: int, hours: float) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        journal = Path(tmp) / "bench.log"
        cmd = [sys.executable, "-m", "softsensor.cli", "calibrate", str(day_path), "--trials",
               str(n_trials), "--quiet", "--no-polish", "--no-identify", "--storage",
               f"journal:{journal}", "--study-name", "bench", "--seed", str(seed),
               "--window-hours", str(hours)]
        # warm the compiled-model cache and the imports outside the timing
        subprocess.run([sys.executable, "-c", "import softsensor.calibration.pipeline"],
                       check=True)
        t0 = time.perf_counter()
        procs = [subprocess.Popen(cmd + ["--out", str(Path(tmp) / f"p{i}.toml")],
                                  stdout=subprocess.DEVNULL) for i in range(2)]
        for p in procs:
            if p.wait() != 0:
                raise RuntimeError("a worker failed")
        return (time.perf_counter() - t0) / n_trials


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--hours", type=float, default=48.0)
    ap.add_argument("--seed", type=int, default=0, help="TPE seed")
    ap.add_argument("--day-seed", type=int, default=11, help="virtual-plant seed")
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--compare", action="store_true",
                    help="also time sequential / batch8 / workers2 / threads2 per trial")
    ap.add_argument("--compare-trials", type=int, default=24)
    args = ap.parse_args()
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    config = load_plant_config()
    truth_cfg = config.with_parameters(TRUTH)
    t0 = time.perf_counter()
    day = simulate_day(truth_cfg, args.hours, seed=args.day_seed)
    t_day = time.perf_counter() - t0
    seg = segment_from_day(day, config, source=f"virtual plant seed {args.day_seed}")
    model = DryerModel(config)
    model.simulate(seg.U[None, :2], model.theta0)  # compile / load the cache outside timing
    truth_fit = evaluate_fit(simulate_segments(model, [seg], truth_cfg.parameter_vector()),
                             [seg], config.cost.weights())[0]
    load_before = os.getloadavg()
    settings = StudySettings(n_trials=args.trials, seed=args.seed, batch=args.batch,
                             progress=False)
    result = calibrate([seg], config, settings, model=model, identify=False)
    s = result.summary()
    out = {
        "day": {"hours": args.hours, "seed": args.day_seed, "windows": seg.n_windows,
                "lab_samples": int(len(seg.lab_value)), "simulate_day_s": round(t_day, 1)},
        "trials": args.trials,
        "batch": args.batch,
        "study_wall_time_s": round(result.timings["study"], 1),
        "polish_wall_time_s": round(result.timings.get("refine", 0.0), 1),
        "total_wall_time_s": round(result.timings["total"], 1),
        "pruned_share": round(s["pruned_share"], 3),
        "tpe_best_trial": result.tpe_best["trial"],
        "tpe_best_cost": result.tpe_best["cost"],
        "polish_simulations": s["refine_simulations"],
        "final_cost": result.fit.cost,
        "cost_at_truth": truth_fit.cost,
        "final_over_truth": result.fit.cost / truth_fit.cost,
        "cost_at_config": s["cost_at_config"],
        "params_over_truth": {k: round(v / TRUTH[k], 4) for k, v in result.params.items()},
        "paper": {"trials": 200, "wall_time_s": 4.2 * 3600, "machine": "Intel i9, 64 GB"},
        "load_average_1min": [round(load_before[0], 2), round(os.getloadavg()[0], 2)],
        "cpus": os.cpu_count(),
    }
    if args.compare:
        n = args.compare_trials
        tmp = Path(tempfile.mkdtemp())
        day_path = day.write(tmp / "bench.mcap")
        per = {}
        for name, batch in (("sequential", 1), ("batch8", 8)):
            r = calibrate([seg], config, StudySettings(n_trials=n, seed=args.seed, batch=batch,
                                                       progress=False),
                          model=model, polish=False, identify=False)
            per[name] = round(r.timings["study"] / n, 3)
        per["workers2"] = round(_time_workers(day_path, n, args.seed, args.hours), 3)
        per["sequential_no_prune"] = round(_time_sequential_no_prune(model, seg, config, 8,
                                                                      args.seed), 3)
        per["threads2_no_prune"] = round(_time_threads(model, seg, config, 8, args.seed), 3)
        out["seconds_per_trial"] = per
        out["compare_trials"] = n
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
