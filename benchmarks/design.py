"""Designed experiment against natural operation, on the independent plant (issue 15).

The calibration (:func:`softsensor.calibration.calibration_run.calibrate`, the code of ``softsensor
calibrate``) is run twice on one independent-plant member (:mod:`softsensor.plant.independent`,
``--plant-seed``), a dryer the model is not:

* **natural**: 48 h (``--natural-hours``) of a clean natural day, its own lab schedule (a
  sample every 2 to 4 h);
* **designed**: a 6 h (``--hours``) period that follows the schedule ``softsensor design``
  proposes (:mod:`softsensor.apps.design`, designed at the config's parameters and the
  natural day's median operating point, D-optimal, default limits: T_sp +-2 K at 0.5 K/min,
  m_air +-5 %, predicted outlet-moisture excursion <= 0.01 kg/kg) with a lab sample every
  30 min, recorded on the same plant on another day seed (its disturbances run as usual).

Each is scored by the identifiability analysis at its calibrated point (``identify``, profile
test included: relative standard errors of ln theta, the weighted FIM's condition number,
the verdicts) and by eq. 4 on an independent validation day of the same plant (24 h, inlet
moisture fitted to the temperatures only, as ``softsensor validate``). With ``--rounds 2`` a
second designed period is designed at the first estimate, recorded, and both periods are
calibrated together (sequential design); the standard errors after each round are reported.

Targets (issue 15): condition number at least 10x smaller than natural, at least three
parameters identifiable to 15 % (verdict ``identifiable``), lower validation cost. They are
reported as measured, met or not.

    python benchmarks/design.py [--plant-seed 0] [--trials 100] [--budget 30] [--rounds 2]
        [--out FILE] [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any

import numpy as np

from softsensor.apps.design import (
    DEFAULT_NOISE,
    build_problem,
    operating_point_of,
    record_schedule,
)
from softsensor.calibration.calibration_run import calibrate, objective_spec
from softsensor.calibration.dataset import Segment, segment_from_day
from softsensor.calibration.experiment_design import DesignLimits, optimise
from softsensor.calibration.identifiability import identify
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.settings import calibration_settings
from softsensor.calibration.validation import validate
from softsensor.jsonable import jsonable
from softsensor.model import DryerModel
from softsensor.plant.independent import simulate_independent_day
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import PARAMETER_NAMES, load_plant_config
from softsensor.signals import INPUT_NAMES

DAY_NS = 86_400 * 10**9


def log(text: str) -> None:
    print(f"design benchmark: {text}", file=sys.stderr, flush=True)


def calibrate_and_score(segments: list[Segment], val: list[Segment], base, settings,
                        trials: int, label: str) -> dict[str, Any]:
    """Calibrate on ``segments``, identify there, validate on ``val``."""
    t0 = time.perf_counter()
    res = calibrate(segments, base, StudySettings(n_trials=trials, seed=0, progress=False),
                    settings, validation_segments=[], identify_result=False)
    model = DryerModel(base)
    spec = objective_spec(model, segments, base, settings)
    ident, _ = identify(model, segments, res.theta, spec, base.bounds())
    vspec = objective_spec(model, val, base, settings)
    v = validate(val, base, vspec, res.theta, model=model)
    v0 = validate(val, base, vspec, base.parameter_vector(), model=model)
    out = {
        "label": label, "hours": float(sum(s.hours for s in segments)),
        "lab_samples": int(sum(len(s.lab_value) for s in segments)),
        "theta": dict(zip(PARAMETER_NAMES, map(float, res.theta), strict=True)),
        "relative_se": {v_.name: v_.relative_se for v_ in ident.verdicts},
        "verdicts": {v_.name: v_.verdict for v_ in ident.verdicts},
        "identifiable": ident.identifiable,
        "fim_condition_number": ident.condition_number,
        "within_15pct_by_se": [v_.name for v_ in ident.verdicts if 2 * v_.relative_se <= 0.15],
        "validation_cost": float(v.fit.cost), "validation_rmse": dict(v.fit.rmse),
        "validation_cost_config_params": float(v0.fit.cost),
        "wall_s": round(time.perf_counter() - t0, 1)}
    log(f"{label}: condition {ident.condition_number:.3g}, identifiable "
        f"{ident.identifiable}, validation cost {out['validation_cost']:.4g} "
        f"({out['wall_s']} s)")
    return out



def design_round(base, theta, op, limits, settings, budget: int, seed: int):
    prob = build_problem(base, base.with_parameters(np.asarray(theta, float)), op, limits,
                         settings, DEFAULT_NOISE)
    t0 = time.perf_counter()
    res = optimise(prob, seed=seed, budget=budget)
    log(f"design at round start: criterion {res.best.score:.4g} (natural "
        f"{res.natural.score:.4g}), excursion {res.best.excursion:.4f} kg/kg, "
        f"{len(res.history)} evaluations, {time.perf_counter() - t0:.0f} s")
    return res, time.perf_counter() - t0


def targets(nat: dict[str, Any], des: dict[str, Any]) -> dict[str, Any]:
    ratio = nat["fim_condition_number"] / des["fim_condition_number"]
    return {
        "condition_ratio_natural_over_design": ratio,
        "condition_10x_smaller": bool(ratio >= 10.0),
        "identifiable_design": len(des["identifiable"]),
        "three_identifiable_to_15pct": bool(len(des["identifiable"]) >= 3),
        "lower_validation_cost": bool(des["validation_cost"] < nat["validation_cost"]),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("independent", "model"), default="independent",
                    help="model: the matched plant, the floor beside the independent one")
    ap.add_argument("--plant-seed", type=int, default=0)
    ap.add_argument("--natural-hours", type=float, default=48.0)
    ap.add_argument("--hours", type=float, default=6.0)
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--budget", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--quick", action="store_true", help="12 h natural, 3 h designed, "
                                                          "10 trials, budget 8, 1 round")
    a = ap.parse_args(argv)
    if a.quick:
        a.natural_hours, a.hours, a.trials, a.budget, a.rounds = 12.0, 3.0, 10, 8, 1
    base = load_plant_config(None)
    settings = calibration_settings(base)
    t0 = time.perf_counter()
    if a.plant == "independent":
        def day(hours: float, seed: int, **kw: Any):
            return simulate_independent_day(base, hours, seed, plant_seed=a.plant_seed, **kw)
    else:  # the matched plant (the model itself, config parameters): the floor
        def day(hours: float, seed: int, **kw: Any):
            return simulate_day(base, hours, seed, **kw)
    nat_day = day(a.natural_hours, 101)
    val_day = day(24.0, 103, start_ns=int(nat_day.scans.index[-1]) + 30 * DAY_NS)
    nat_seg = segment_from_day(nat_day, base, source="natural seed 101")
    val = [segment_from_day(val_day, base, source="validation seed 103")]
    log(f"days simulated ({time.perf_counter() - t0:.0f} s)")
    natural = calibrate_and_score([nat_seg], val, base, settings, a.trials, "natural")
    # the designed periods start a day after the natural one (as benchmarks/results/design.json did)
    op = operating_point_of(nat_day, base, a.hours, "natural seed 101")
    op = dataclasses.replace(op, start_ns=op.start_ns + DAY_NS)
    m0 = float(op.u[INPUT_NAMES.index("m_air")])
    limits = DesignLimits(T_sp_band=(op.T_sp - 2.0, op.T_sp + 2.0),
                          m_air_band=(0.95 * m0, 1.05 * m0), hours=a.hours)
    theta, recorded, rounds = base.parameter_vector(), [], []
    for r in range(a.rounds):
        res, wall = design_round(base, theta, op, limits, settings, a.budget, r)
        start = op.start_ns + r * DAY_NS
        recorded.append(record_schedule(base, res.best.schedule, limits, 201 + r,
                                        a.plant, a.plant_seed, start))
        score = calibrate_and_score(list(recorded), val, base, settings, a.trials,
                                    f"designed round {r + 1}")
        score.update(design_criterion=res.best.score, design_natural_criterion=res.natural.score,
                     design_excursion=res.best.excursion, design_wall_s=round(wall, 1),
                     design_gain_logdet=res.best.score - res.natural.score)
        rounds.append(score)
        theta = np.array([score["theta"][n] for n in PARAMETER_NAMES])
    doc = {"plant": a.plant, "plant_seed": a.plant_seed, "trials": a.trials,
           "limits": limits.__dict__, "natural": natural, "designed_rounds": rounds,
           "targets_round_1": targets(natural, rounds[0]),
           "wall_s": round(time.perf_counter() - t0, 1)}
    text = json.dumps(jsonable(doc), indent=2)
    print(text)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
