"""Benchmark of ``softsensor calibrate``: 200 TPE trials on a 48 h virtual-plant day, on one
core and on two; and a calibration from history, 7 independent-plant records of 48 h.

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

The history case (:func:`history`, issues 21 and 41: 7 records of 48 h, 200 trials, in at
most 120 s on two cores, the structure search included) runs what ``softsensor calibrate
DAY.mcap ...`` runs with its defaults (:func:`~softsensor.calibration.history_calibration.
calibrate_history`: 12 h windows picked across the records up to 96 h, 200 trials, the
polish, validation on the held-out hours, the identifiability analysis, the structure search
and the sensor's decision on what it adopts, the per-day inlet levels and the model error)
on consecutive 48 h records of one independent plant (``--plant-seed``), and prints per
phase (study, refine, validate, identify, structure, sensor_score, model_error) the wall and
CPU seconds, what the calibration reached (the objective after TPE and after the polish, the
held-out validation against the config's parameters, the deployed parameters and the
structure adopted, with every alternative's gain) and whether the targets of
``targets.json`` (``calibrate_history``; ``calibrate_one_day`` with ``--records 1``, which
runs the one-day defaults: the 48 h window, no structure search) are met. ``--records
2,7,14`` runs it on the first 2, 7 and 14 records and fits the seconds to ``a + b x
records``: the study, the polish and the analysis run on at most ``--fit-hours`` of windows
whatever the history's length, the validation and the model error on the rest of every
record, so the time grows linearly with the records.

    python benchmarks/calibrate.py [--case day|history|all] [--trials 200] [--hours 48]
        [--seed 0] [--batch 1] [--records 7] [--plant-seed 7]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import optuna

from softsensor.apps.calibrate import (
    HISTORY_FIT_HOURS,
    default_structure,
    default_window_hours,
)
from softsensor.calibration.calibration_run import calibrate
from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.history_calibration import calibrate_history
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.selection import DEFAULT_MIN_LABS
from softsensor.calibration.settings import calibration_settings
from softsensor.model import DryerModel
from softsensor.plant.day import DEFAULT_START_NS
from softsensor.plant.independent.simulator import simulate_independent_day
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config

TRUTH = {"mult_D": 0.7, "mult_C": 2.0, "mult_h": 1.4, "mult_k": 2.0, "mult_p": 1.8,
         "hm_cyc": 3e-4, "hc_cyc": 50.0}
_ALL_TARGETS = json.loads((Path(__file__).with_name("targets.json")).read_text())
TARGETS = _ALL_TARGETS["calibrate"]
HISTORY_TARGETS = _ALL_TARGETS["calibrate_history"]
ONE_DAY_TARGETS = _ALL_TARGETS["calibrate_one_day"]
#: Phases of a calibration from history, as its timings name them (the structure search and
#: the sensor's decision on what it adopted run with several records, as ``calibrate`` runs).
PHASES = ("study", "refine", "validate", "identify", "structure", "sensor_score",
          "model_error")
#: Seed of the first record's day (the next ones count up).
FIRST_DAY_SEED = 1000


class TimedModel(DryerModel):
    """The dryer model, adding up the wall seconds its ``simulate`` calls take and the
    windows they simulate (summed over batch members; a lab sample's partial window counts
    as one) in ``tally``, which the search's copy of the model
    (:func:`~softsensor.calibration.calibration_run.search_model`) shares."""

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


def records(config, n: int, hours: float, plant_seed: int) -> list:
    """``n`` consecutive records of one independent plant, as the calibration reads them."""
    out = []
    for i in range(n):
        day = simulate_independent_day(config, hours, FIRST_DAY_SEED + i, plant_seed=plant_seed,
                                       start_ns=DEFAULT_START_NS + int(i * hours * 3.6e12))
        out.append(segment_from_day(day, config, source=f"plant {plant_seed} record {i}"))
    return out


def _rounded(d: dict | None) -> dict | None:
    return None if d is None else {k: round(float(v), 5) for k, v in d.items()}


def history(days: list, config, trials: int, seed: int) -> dict:
    """``softsensor calibrate``'s defaults on the records ``days``: wall and CPU seconds per
    phase and what the calibration reached."""
    model = DryerModel(config)
    for n in {1, model.wall_substeps}:  # compile / load the cache outside timing
        DryerModel(config, wall_substeps=n).simulate(days[0].U[None, :2], model.theta0)
    # the verb's default windows: the paper's 48 h for one day
    window_hours = default_window_hours(len(days))
    load = os.getloadavg()[0]
    w0, c0 = time.perf_counter(), time.process_time()
    h = calibrate_history(days, config, StudySettings(n_trials=trials, seed=seed,
                                                      progress=False),
                          calibration_settings(config), current_theta=config.parameter_vector(),
                          window_hours=window_hours, fit_hours=HISTORY_FIT_HOURS,
                          min_labs=DEFAULT_MIN_LABS, model=model,
                          # the verb's default: the structure searched with several days
                          structure=default_structure(config, len(days)))
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    r, t = h.calibration, h.timings
    ref = r.refinement
    val, cur = r.validation, r.current_validation
    return {
        "records": len(days), "hours": round(sum(d.hours for d in days), 1),
        "window_hours": window_hours,
        "fit_hours": round(sum(s.hours for s in r.segments), 1),
        "held_out_hours": None if val is None else round(sum(s.hours for s in val.segments), 1),
        "phases": {p: {"wall_s": round(t[p], 2), "cpu_s": None if f"{p}_cpu" not in t
                       else round(t[f"{p}_cpu"], 2)} for p in PHASES if p in t},
        "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
        "load_average_1min": [round(load, 2), round(os.getloadavg()[0], 2)],
        "tpe_best_objective": round(float(r.tpe_best["objective"]), 6),
        "objective": round(float(r.evaluation.objective), 6),
        "cost": round(float(r.fit.cost), 6),
        "refine_simulations": None if ref is None else ref.simulations,
        "refine_jacobian_simulations": None if ref is None else getattr(ref, "jac_simulations",
                                                                        None),
        "validation_score": None if val is None else round(float(val.score), 6),
        "current_validation_score": None if cur is None else round(float(cur.score), 6),
        "validation_rmse": None if val is None else _rounded(val.fit.rmse),
        "current_validation_rmse": None if cur is None else _rounded(cur.fit.rmse),
        "accepted": r.accepted,
        "identifiable": None if r.identifiability is None else r.identifiability.identifiable,
        "deployed_params": _rounded(h.params),
        "structure": None if h.structure is None else {
            "adopted": None if h.structure.adopted is None
            else h.structure.adopted.candidate.name,
            "gains": {c.candidate.name: round(float(c.gain), 3)
                      for c in h.structure.candidates}},
    }


def linear_in_records(runs: list[dict]) -> dict:
    """Least-squares ``seconds = a + b x records`` of the total and of every phase."""
    n = np.array([r["records"] for r in runs], float)
    A = np.column_stack([np.ones_like(n), n])

    def fit(y: list) -> dict:
        (a, b), *_ = np.linalg.lstsq(A, np.asarray(y, float), rcond=None)
        return {"a_s": round(float(a), 2), "b_s_per_record": round(float(b), 2)}

    out = {"cpu_s": fit([r["cpu_s"] for r in runs]), "wall_s": fit([r["wall_s"] for r in runs])}
    for p in PHASES:
        if all(r["phases"].get(p, {}).get("cpu_s") is not None for r in runs):
            out[p] = fit([r["phases"][p]["cpu_s"] for r in runs])
    return out


def day_case(config, args) -> dict:
    day = simulate_day(config.with_parameters(TRUTH), args.hours, seed=args.day_seed)
    seg = segment_from_day(day, config, source=f"virtual plant seed {args.day_seed}")
    one = study(seg, config, args.trials, args.seed, args.batch, threads=1)
    two = study(seg, config, args.trials, args.seed, args.batch, threads=2)
    # the same study searched with the full model: what the faster search costs in quality
    full = study(seg, config, args.trials, args.seed, args.batch, threads=2,
                 search_wall_substeps=0)
    ratio = one["study_wall_s"] / two["study_wall_s"]
    standard = args.trials == TARGETS["trials"] and args.hours == TARGETS["hours"]
    return {
        "day": {"hours": args.hours, "seed": args.day_seed, "windows": seg.n_windows,
                "lab_samples": int(len(seg.lab_value))},
        "trials": args.trials, "batch": args.batch, "seed": args.seed,
        "one_core": one, "two_cores": two, "two_cores_full_model_search": full,
        "full_over_fast_search_wall": round(full["study_wall_s"] / two["study_wall_s"], 3),
        "one_over_two_cores_wall": round(ratio, 3),
        "same_best_cost": one["best_cost"] == two["best_cost"],
        "paper": {"trials": 200, "wall_time_s": 4.2 * 3600, "machine": "Intel i9, 64 GB"},
        "targets": TARGETS,
        "meets_targets": None if not standard else {
            "study_wall_two_cores_at_most_s":
                two["study_wall_s"] <= TARGETS["study_wall_two_cores_at_most_s"],
            "one_over_two_cores_wall_at_least":
                ratio >= TARGETS["one_over_two_cores_wall_at_least"],
        },
    }


def history_case(config, args) -> dict:
    counts = sorted({int(x) for x in args.records.split(",")})
    days = records(config, max(counts), HISTORY_TARGETS["hours_per_record"], args.plant_seed)
    runs = [history(days[:n], config, args.trials, args.seed) for n in counts]
    T = HISTORY_TARGETS
    met = {}
    for key, tt in (("history", T), ("one_day", ONE_DAY_TARGETS)):
        at = next((r for r in runs if r["records"] == tt["records"]), None)
        if args.trials == tt["trials"] and args.plant_seed == tt["plant_seed"] and at:
            met[f"{key}_wall_two_cores_at_most_s"] = (at["wall_s"]
                                                      <= tt["wall_two_cores_at_most_s"])
    return {
        "plant_seed": args.plant_seed, "first_day_seed": FIRST_DAY_SEED,
        "hours_per_record": T["hours_per_record"], "trials": args.trials,
        "fit_hours": HISTORY_FIT_HOURS, "runs": runs,
        "linear_in_records": linear_in_records(runs) if len(runs) > 1 else None,
        "targets": {"history": T, "one_day": ONE_DAY_TARGETS},
        # wall seconds: met or not on quiet cores only (see each run's load average)
        "meets_targets": met or None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("day", "history", "all"), default="all")
    ap.add_argument("--trials", type=int, default=TARGETS["trials"])
    ap.add_argument("--hours", type=float, default=TARGETS["hours"])
    ap.add_argument("--seed", type=int, default=0, help="TPE seed")
    ap.add_argument("--day-seed", type=int, default=11, help="virtual-plant seed")
    ap.add_argument("--batch", type=int, default=1, help="trials asked of TPE at once")
    ap.add_argument("--records", default=str(HISTORY_TARGETS["records"]),
                    help="history records (48 h each), comma-separated for several runs")
    ap.add_argument("--plant-seed", type=int, default=HISTORY_TARGETS["plant_seed"],
                    help="the independent plant of the history case")
    args = ap.parse_args()
    if args.trials < 1 or args.batch < 1 or not args.hours > 0:
        ap.error("--trials and --batch must be >= 1 and --hours > 0")
    if not all(x.strip().isdigit() and int(x) >= 1 for x in args.records.split(",")):
        ap.error(f"--records must be counts >= 1, got {args.records!r}")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    config = load_plant_config()
    out: dict = {"cpus": os.cpu_count()}
    if args.case in ("day", "all"):
        out.update(day_case(config, args))
    if args.case in ("history", "all"):
        out["history"] = history_case(config, args)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
