"""Does the history calibration reach the best fit its structure allows? (issue 28 item 1)

On the matched plant (the model itself at known parameters, ``open_world.SHIFTED``), NDAYS
records of HOURS are calibrated with ``calibrate``'s defaults (windows across the days, the
study of TRIALS trials, the polish, validation on the held-out hours, identifiability); the
result and the true parameters are then scored on the same held-out pieces, eq. 4 with the
inlet read from the temperatures and open loop. Target: the ratio at most 1.25.

    python benchmarks/calibrate_matched.py 7 48 200 benchmarks/results/calibrate_matched.json

Simulated days are cached under ``--cache`` (default a temporary folder)."""
import json
import pathlib
import pickle
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from open_world import SHIFTED

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.history_calibration import calibrate_history
from softsensor.calibration.optimize import StudySettings
from softsensor.calibration.settings import calibration_settings
from softsensor.calibration.validation import validate_many
from softsensor.model import DryerModel
from softsensor.plant.day import DEFAULT_START_NS
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import PARAMETER_NAMES, load_plant_config


def main() -> None:
    ndays, hours, trials = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3])
    out = sys.argv[4]
    base = load_plant_config()
    truth = base.with_parameters(SHIFTED)
    cache = pathlib.Path(tempfile.mkdtemp(prefix="calibrate_matched_"))
    day_ns = 86400 * 10**9
    days = []
    for i in range(ndays):
        p = cache / f"mh_{i}_{hours}.pkl"
        if p.exists():
            d = pickle.loads(p.read_bytes())
        else:
            d = simulate_day(truth, hours, 3000 + i, start_ns=DEFAULT_START_NS + i * 2 * day_ns)
            p.write_bytes(pickle.dumps(d))
        days.append(segment_from_day(d, base, source=f"d{i}"))
    t0, c0 = time.time(), time.process_time()
    h = calibrate_history(days, base, StudySettings(n_trials=trials, seed=0, progress=False),
                          calibration_settings(base), current_theta=base.parameter_vector(),
                          window_hours=12.0, fit_hours=96.0, identify_result=True)
    wall, cpu = time.time() - t0, time.process_time() - c0
    res = h.calibration
    thetas = [h.theta, truth.parameter_vector(), base.parameter_vector()]
    vs = validate_many(res.validation.segments, base, res.spec, thetas, [None] * 3,
                       DryerModel(base))
    rec = {"days": ndays, "hours": hours, "trials": trials, "wall_s": wall, "cpu_s": cpu,
           "timings": h.timings, "truth": SHIFTED,
           "found": dict(zip(PARAMETER_NAMES, map(float, h.theta), strict=True))}
    for name, v in zip(["found", "truth", "defaults"], vs, strict=True):
        ev = v.evaluation
        rec[name] = {"eq4_inlet_read": ev.fit.cost, "eq4_open_loop": ev.open_fit.cost,
                     "rmse_inlet_read": dict(ev.fit.rmse),
                     "rmse_open_loop": dict(ev.open_fit.rmse)}
    for mode in ("inlet_read", "open_loop"):
        rec[f"ratio_eq4_{mode}"] = rec["found"][f"eq4_{mode}"] / rec["truth"][f"eq4_{mode}"]
    rec["trade_off"] = res.trade_off.as_dict() if res.trade_off else None
    ident = res.identifiability
    rec["weakest_directions"] = ident.weakest_directions() if ident else None
    rec["identifiable"] = ident.identifiable if ident else None
    pathlib.Path(out).write_text(json.dumps(rec, indent=1, default=float))
    print(json.dumps({k: rec[k] for k in ("wall_s", "cpu_s", "ratio_eq4_inlet_read",
                                          "ratio_eq4_open_loop")}, default=float))


if __name__ == "__main__":
    main()
