"""Benchmark of ``softsensor calibrate``: 200 TPE trials on a 48 h virtual-plant day, on one
core and on two.

The study runs as ``softsensor calibrate`` runs it (the config's ``[calibration]`` settings:
the inlet moisture estimated, the prior, a quarter of the day held out, pruning over four
chunks, seed 0), twice in one process: with the model's batch members in one thread
(``DryerModel(threads=1)``: one core) and in two (``threads=2``). Every trial simulates two
members, the parameter set as it is and with the inlet moisture raised (the objective's
sensitivity to it, :mod:`softsensor.calibration.objective`), in one batched call whose members
run on the two cores (the kernels release the GIL). Both runs ask TPE the same trials with
the same seed, so their best costs must match.

Prints one JSON document: per run the study's wall and CPU seconds, the seconds spent inside
``DryerModel.simulate`` and the windows it simulated summed over members (where the time
goes), pruned trials and best cost; the one-core over
two-core ratio; the load average (the machine may be shared); whether the targets of
``benchmarks/targets.json`` (``calibrate``) are met. The paper needed 4.2 h on an i9
workstation for its 200 trials.

    python benchmarks/calibrate.py [--trials 200] [--hours 48] [--seed 0] [--batch 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import optuna

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.pipeline import calibrate
from softsensor.calibration.settings import calibration_settings
from softsensor.model import DryerModel
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config

TRUTH = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
         "hm_cyc": 3e-4, "hc_cyc": 50.0}
TARGETS = json.loads((Path(__file__).with_name("targets.json")).read_text())["calibrate"]


class TimedModel(DryerModel):
    """The dryer model, adding up the wall seconds its ``simulate`` calls take and the
    windows they simulate (summed over batch members; a lab sample's partial window counts
    as one) in ``tally``, which the search's copy of the model
    (:func:`~softsensor.calibration.pipeline.search_model`) shares."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.tally = {"seconds": 0.0, "windows": 0}

    def simulate(self, *args, **kwargs):
        t0 = time.perf_counter()
        Y, state = super().simulate(*args, **kwargs)
        self.tally["seconds"] += time.perf_counter() - t0
        self.tally["windows"] += Y[..., 0].size
        return Y, state


def study(seg, config, trials: int, seed: int, batch: int, threads: int,
          search_wall_substeps: int | None = None) -> dict:
    """One study of ``trials`` trials with the model's members on ``threads`` threads (and
    the search's wall substeps given, else the config's ``[calibration]`` value)."""
    model = TimedModel(config, threads=threads)
    for n in {1, model.wall_substeps}:  # compile / load the cache outside timing
        TimedModel(config, threads=threads, wall_substeps=n).simulate(seg.U[None, :2],
                                                                     model.theta0)
    cal = calibration_settings(config)
    if search_wall_substeps is not None:
        cal = dataclasses.replace(cal, search_wall_substeps=search_wall_substeps)
    load = os.getloadavg()[0]
    w0, c0 = time.perf_counter(), time.process_time()
    r = calibrate([seg], config, StudySettings(n_trials=trials, seed=seed, batch=batch,
                                               progress=False),
                  cal, model=model, polish=False, identify_result=False)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    n_win = model.tally["windows"]
    return {"threads": threads, "search_wall_substeps": cal.search_wall_substeps or
            model.wall_substeps, "study_wall_s": round(r.timings["study"], 2),
            "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "model_simulate_wall_s": round(model.tally["seconds"], 2),
            "model_share_of_wall": round(model.tally["seconds"] / wall, 3),
            "member_windows": n_win,
            "cpu_ms_per_member_window": round(1e3 * cpu / n_win, 3),
            # the search's best point evaluated with the config's full wall substeps
            "best_cost_full_model": round(float(r.evaluation.fit.cost), 6),
            "pruned": r.pruned_here, "best_cost": r.study.best_value,
            "best_trial": r.study.best_trial.number,
            "load_average_1min": [round(load, 2), round(os.getloadavg()[0], 2)]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=TARGETS["trials"])
    ap.add_argument("--hours", type=float, default=TARGETS["hours"])
    ap.add_argument("--seed", type=int, default=0, help="TPE seed")
    ap.add_argument("--day-seed", type=int, default=11, help="virtual-plant seed")
    ap.add_argument("--batch", type=int, default=1, help="trials asked of TPE at once")
    args = ap.parse_args()
    if args.trials < 1 or args.batch < 1 or not args.hours > 0:
        ap.error("--trials and --batch must be >= 1 and --hours > 0")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    config = load_plant_config()
    day = simulate_day(config.with_parameters(TRUTH), args.hours, seed=args.day_seed)
    seg = segment_from_day(day, config, source=f"virtual plant seed {args.day_seed}")
    one = study(seg, config, args.trials, args.seed, args.batch, threads=1)
    two = study(seg, config, args.trials, args.seed, args.batch, threads=2)
    # the same study searched with the full model: what the faster search costs in quality
    full = study(seg, config, args.trials, args.seed, args.batch, threads=2,
                 search_wall_substeps=0)
    ratio = one["study_wall_s"] / two["study_wall_s"]
    standard = args.trials == TARGETS["trials"] and args.hours == TARGETS["hours"]
    out = {
        "day": {"hours": args.hours, "seed": args.day_seed, "windows": seg.n_windows,
                "lab_samples": int(len(seg.lab_value))},
        "trials": args.trials, "batch": args.batch, "seed": args.seed,
        "one_core": one, "two_cores": two, "two_cores_full_model_search": full,
        "full_over_fast_search_wall": round(full["study_wall_s"] / two["study_wall_s"], 3),
        "one_over_two_cores_wall": round(ratio, 3),
        "same_best_cost": one["best_cost"] == two["best_cost"],
        "cpus": os.cpu_count(),
        "paper": {"trials": 200, "wall_time_s": 4.2 * 3600, "machine": "Intel i9, 64 GB"},
        "targets": TARGETS,
        "meets_targets": None if not standard else {
            "study_wall_two_cores_at_most_s":
                two["study_wall_s"] <= TARGETS["study_wall_two_cores_at_most_s"],
            "one_over_two_cores_wall_at_least":
                ratio >= TARGETS["one_over_two_cores_wall_at_least"],
        },
    }
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
