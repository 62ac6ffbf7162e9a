"""Events the model cannot explain: does the sensor turn them into moisture?

On an independent plant calibrated from its history (the code of ``softsensor calibrate
DAY...`` with its defaults, through :mod:`open_world`'s plan and cache), fresh days of five
kinds are estimated beside the peers and the plant's own perfect-model floor:

* ``surge``: the fan's true flow oscillates (amplitude 2 to 6 %, ``--surge``; period 1.5 to
  2 h) while the recorded ``m_air`` stays flat
  (:class:`softsensor.plant.independent.UnmeasuredFlow`);
* ``input_lag``: the ``T_air_in`` reading lags the truth by 10 to 25 min (CONTRACT cause);
* ``moves``: production changes every 1 to 2 h, each with a set-point move;
* ``inlet``: the inlet moisture steps and drifts by 0.08 to 0.2 kg/kg (CONTRACT cause): the
  change the temperatures should be read as;
* ``none``: a clean day.

Per day: the outlet-moisture RMSE of the published estimate, the physics alone, holding the
last lab, the lab-bias-updated regression and the floor; the **swing ratio** (standard
deviation of the estimate after removing its daily mean, over the truth's), the 95 % band's
coverage and the inlet-moisture RMSE. Ticks before the first lab result are not scored.

    python benchmarks/sensor_events.py --seed N [--plant-seeds S,...] [--days 1]
        [--cache DIR] [--out FILE]

The plan (plant seeds, history and day seeds) comes from ``--seed`` as in
:mod:`open_world`; ``--cache`` shares its simulated days and calibrations.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import open_world as ow  # noqa: E402
import peers  # noqa: E402
import provenance  # noqa: E402

from softsensor.estimation.ukf import UkfEstimator  # noqa: E402
from softsensor.jsonable import jsonable  # noqa: E402
from softsensor.plant.day import DEFAULT_START_NS, SimulatedDay  # noqa: E402
from softsensor.plant.independent import UnmeasuredFlow, simulate_independent_day  # noqa: E402
from softsensor.plant.independent.open_loop import open_loop_day  # noqa: E402
from softsensor.plant.settings import virtual_plant_settings  # noqa: E402
from softsensor.plantconfig import (  # noqa: E402
    PlantConfig,
    load_parameters,
    load_plant_config,
    with_table,
)

KINDS = ("none", "surge", "input_lag", "moves", "inlet")


def swing(x: np.ndarray) -> float:
    """Standard deviation after removing the mean (NaN ignored)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    return float(np.std(x - x.mean())) if x.size > 1 else math.nan


def moves_config(base: PlantConfig) -> PlantConfig:
    """``base`` with production changes every 1 to 2 h, each with a set-point move."""
    s = virtual_plant_settings(base)
    table = {k: getattr(s, k) for k in s.__dataclass_fields__}
    table.update(production_hold_min=3600.0, production_hold_max=7200.0,
                 setpoint_change_probability=1.0)
    return with_table(base, "virtual_plant", table)


#: Relative amplitude range of the unmeasured flow's surge [-] (the published runs').
SURGE = (0.02, 0.06)


def event_day(base: PlantConfig, hours: float, kind: str, plant_seed: int, seed: int,
              date: int, rng: np.random.Generator, surge: tuple[float, float] = SURGE
              ) -> tuple[SimulatedDay, dict[str, Any]]:
    """Simulate one ``hours`` event day of ``kind`` (module docstring) on plant
    ``plant_seed``; the day and what was drawn for it."""
    start = DEFAULT_START_NS + date * ow.DAY_NS
    config, effect, magnitude, flow = base, None, None, None
    info: dict[str, Any] = {"kind": kind, "seed": seed}
    if kind == "surge":
        flow = UnmeasuredFlow(float(rng.uniform(*surge)),
                              float(rng.uniform(1.5, 2.0)) * 3600.0,
                              float(rng.uniform(0.0, 2 * math.pi)))
        info["unmeasured_flow"] = dataclasses.asdict(flow)
    elif kind == "input_lag":
        effect, magnitude = "input_lag", float(rng.uniform(10.0, 25.0))
        info["lag_min"] = magnitude
    elif kind == "moves":
        config = moves_config(base)
    elif kind == "inlet":
        effect, magnitude = "inlet_moisture", float(rng.uniform(0.08, 0.2))
        info["inlet_step"] = magnitude
    day = simulate_independent_day(config, hours, seed, effect, magnitude,
                                   plant_seed=plant_seed, start_ns=start,
                                   unmeasured_flow=flow)
    return day, info


def score_day(config: PlantConfig, regression: peers.Regression | None, day: SimulatedDay,
              base: PlantConfig, plant_seed: int) -> dict[str, Any]:
    """One day: the sensor (``config``, PARAMS.toml read back), its peers (holding the last
    lab, ``regression`` with the lab-bias update) and the plant's own floor (``base``'s
    geometry, plant ``plant_seed``) against the truth (module docstring)."""
    r = ow.run_estimator(config, day)
    ends, labs = r["end"], day.labs
    est = {"softsensor": r["mo"], "physics": r["mo_phys"],
           "hold": peers.hold_last_lab(labs, ends)}
    if regression is not None:
        est["regression"] = peers.regression_peer(regression, day.scans, labs, ends)
    floor = open_loop_day(day.scans, base, plant_seed)["moisture_out"]
    est["floor"] = peers.series_peer(floor, labs, ends)
    truth = ow.truth_at(day, ends, "moisture_out")
    first = labs["log_time_ns"].min() if len(labs) else np.iinfo(np.int64).max
    scored = (ends >= first) & np.isfinite(truth)
    out: dict[str, Any] = {"rmse": {k: ow.rmse((v - truth)[scored]) for k, v in est.items()}}
    t_sw = swing(truth[scored])
    out["swing_truth"] = t_sw
    out["swing_ratio"] = {k: swing(v[scored]) / t_sw for k, v in est.items()}
    ok = scored & np.isfinite(r["mo"]) & np.isfinite(r["mo_sd"])
    out["coverage95"] = float(np.mean((np.abs(r["mo"] - truth) <= 1.96 * r["mo_sd"])[ok]))
    out["moisture_in_rmse"] = ow.rmse((r["mi"] - ow.truth_at(day, ends, "moisture_in"))[scored])
    out["physics_weight_mean"] = float(np.mean(r["w_phys"][scored]))
    out["tick_ms_median"] = 1e3 * float(np.median(r["tick_s"]))
    return out


def warm_start(config: PlantConfig, before: PlantConfig, day_before: SimulatedDay,
               day: SimulatedDay) -> dict[str, float]:
    """The day estimated from a cold start (PARAMS.toml alone) and from the checkpoint of
    the day before, filtered with ``before`` (another calibration, or the same): the
    outlet- and inlet-moisture RMSEs of both."""
    prev = UkfEstimator(before)
    ow.run_estimator(before, day_before, prev)
    warm = UkfEstimator(config)
    warm.restore(json.loads(json.dumps(prev.checkpoint())))
    out = {}
    for name, r in (("cold", ow.run_estimator(config, day)),
                    ("warm", ow.run_estimator(config, day, warm))):
        truth = ow.truth_at(day, r["end"], "moisture_out")
        first = day.labs["log_time_ns"].min()
        scored = (r["end"] >= first) & np.isfinite(truth)
        out[f"{name}_rmse"] = ow.rmse((r["mo"] - truth)[scored])
        out[f"{name}_moisture_in_rmse"] = ow.rmse(
            (r["mi"] - ow.truth_at(day, r["end"], "moisture_in"))[scored])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--seed", type=int, required=True, help="base seed of open_world's plan")
    ap.add_argument("--plant-seeds", default=None, metavar="S,S,...")
    ap.add_argument("--plants", type=int, default=1)
    ap.add_argument("--days", type=int, default=1, help="days per kind and plant")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--event-seed", type=int, default=None,
                    help="draw the event days from this seed (default: --seed)")
    ap.add_argument("--hours", type=float, default=48.0)
    ap.add_argument("--history", type=int, default=7)
    ap.add_argument("--trials", type=int, default=200)
    ap.add_argument("--latest-only", action="store_true")
    ap.add_argument("--estimator", action="append", default=[], metavar="KEY=VALUE",
                    help="an [estimator] setting in place of the shipped one (a trial)")
    ap.add_argument("--surge", default=f"{SURGE[0]},{SURGE[1]}", metavar="LO,HI",
                    help="range of the surge's relative amplitude")
    ap.add_argument("--warm", default=None, metavar="PARAMS.toml|same",
                    help="also start each day from the checkpoint of a clean day before, "
                         "filtered with these parameters ('same': the history's)")
    ap.add_argument("--cache", default=None)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    kinds = [k for k in args.kinds.split(",") if k]
    fixed = [int(x) for x in args.plant_seeds.split(",")] if args.plant_seeds else None
    cfg = load_plant_config()
    book = ow.SeedBook(args.seed)
    plan = ow.make_plan("independent", book, args.plants, args.history, 1, args.hours, fixed)
    days_book = ow.SeedBook(args.event_seed) if args.event_seed is not None else book
    rng = days_book.stream(7, 0)
    t0 = time.perf_counter()
    days_out: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="sensor_events_") as tmp:
        ctx = ow.Context("independent", cfg, cfg, plan, args.hours, args.trials, Path(tmp),
                         Path(args.cache) if args.cache else None, None, True,
                         args.latest_only, True)
        for i, plant_seed in enumerate(plan.plant_seeds):
            m = ow.calibrate_plant(ctx, i)
            if m.config is None:
                ow.say(f"plant {plant_seed}: calibration failed: {m.record.get('error')}")
                continue
            if args.estimator:
                table = dict(m.config.extra.get("estimator", {}))
                for item in args.estimator:
                    key, _, value = item.partition("=")
                    table[key] = json.loads(value)
                m.config = with_table(m.config, "estimator", table)
            ow.say(f"plant {plant_seed}: {m.record.get('reason', '')}")
            date = 100
            for _ in range(args.days):
                for kind in kinds:
                    seed = days_book.draw(rng)
                    day, info = event_day(cfg, args.hours, kind, int(plant_seed), seed, date, rng,
                                          tuple(float(x) for x in args.surge.split(",")))
                    date += 2
                    rec = {"plant_seed": plant_seed, **info,
                           **score_day(m.config, m.regression, day, cfg, int(plant_seed))}
                    if args.warm:
                        before_cfg = m.config if args.warm == "same" else with_table(
                            load_parameters(Path(args.warm), cfg), "estimator",
                            dict(m.config.extra.get("estimator", {})))
                        prev, _ = event_day(cfg, args.hours, "none", int(plant_seed),
                                            days_book.draw(rng), date - 4, rng)
                        rec["warm_start"] = warm_start(m.config, before_cfg, prev, day)
                        ow.say(f"  warm start: {rec['warm_start']}")
                    days_out.append(rec)
                    rm, sw = rec["rmse"], rec["swing_ratio"]
                    ow.say(f"{kind:9s} seed {seed}: " + " ".join(
                        f"{k} {v:.4f}" for k, v in rm.items())
                        + f" | swing x{sw['softsensor']:.2f} (physics x{sw['physics']:.2f})"
                        f" cov {rec['coverage95']:.2f} mi {rec['moisture_in_rmse']:.3f}"
                        f" w {rec['physics_weight_mean']:.2f}")
    out = {"benchmark": "sensor_events", "seed": args.seed, "commit": provenance.commit(),
           "machine": provenance.machine(), "argv": list(sys.argv[1:] if argv is None else argv),
           "days": days_out, "wall_time_s": round(time.perf_counter() - t0, 1)}
    text = json.dumps(jsonable(out), indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n", encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
