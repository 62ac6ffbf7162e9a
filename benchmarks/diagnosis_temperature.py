"""Fit the temperature of the diagnosis's probabilities on tuning days (issue 33 item 2).

The softmax of :mod:`softsensor.diagnosis.posterior` turns the candidates' log-evidences into
probabilities; its temperature is fitted here, on tuning seeds only: independent plant
``--plant`` (default 11, one of the tuning plants 11 to 13), its normal learned from
``--history`` clean days (day seeds 100, 101, ...; as ``tests/diagnosis/test_diagnose_history.py``
does, :func:`~softsensor.calibration.model_error_fit.fit_model_error` at the config's
parameters), then ``--days-per-cause`` test days per cause (day seeds 300, 301, ...,
magnitudes one uniform draw in each stratum of the effect's detectable range) diagnosed
against it. Output: per day the true cause, the verdict and every candidate's
log-evidence, and the temperature minimising the mean Brier score
(:func:`~softsensor.diagnosis.posterior.fit_temperature`) with the Brier score and top-1 and
top-2 accuracy at it and at the module's :data:`~softsensor.diagnosis.posterior.TEMPERATURE`.

    python benchmarks/diagnosis_temperature.py [--plant 11] [--history 4] [--hours 16]
        [--days-per-cause 2] [--out FILE] [--refit FILE]

``--refit FILE`` reads the days of an earlier run's JSON and fits again without diagnosing.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.diagnosis.posterior import TEMPERATURE, fit_temperature, softmax

CAUSES = ("none", "inlet_moisture", "sensor_bias", "lab_delay", "fouling_drift", "input_lag",
          "ambient_heat_loss", "unexplained")


def say(msg: str) -> None:
    print(f"diagnosis_temperature: {msg}", file=sys.stderr, flush=True)


def diagnose_days(args: argparse.Namespace) -> list[dict[str, Any]]:
    from softsensor.calibration.dataset import segment_from_day
    from softsensor.calibration.model_error_fit import fit_model_error
    from softsensor.calibration.params_file import params_document, write_params
    from softsensor.diagnosis.diagnose_day import diagnose
    from softsensor.model.dryer import DryerModel
    from softsensor.plant.effects import EFFECTS
    from softsensor.plant.independent import simulate_independent_day
    from softsensor.plantconfig import load_parameters, load_plant_config

    cfg = load_plant_config()
    hist = [simulate_independent_day(cfg, args.hours, 100 + i, plant_seed=args.plant)
            for i in range(args.history)]
    segs = [segment_from_day(d, cfg, source=f"history {i}") for i, d in enumerate(hist)]
    me = fit_model_error(DryerModel(cfg), segs, cfg.parameter_vector(),
                         float(cfg.nominal.moisture_in))
    values = {n: cfg.parameters[n].value for n in cfg.parameters}
    with tempfile.TemporaryDirectory() as tmp:
        path = write_params(Path(tmp) / "params.toml",
                            params_document(cfg, values, {}, model_error=me.to_table()))
        with_history = load_parameters(path, cfg)
    rng = np.random.default_rng(args.plant)
    days = []
    seed = 300
    n = args.days_per_cause
    for cause in CAUSES:
        if cause == "none":
            mags: list[float | None] = [None] * n
        else:
            lo, hi = EFFECTS[cause].detectable
            mags = [float(lo + (hi - lo) * (j + rng.uniform()) / n) for j in range(n)]
        for mag in mags:
            day = simulate_independent_day(cfg, args.hours, seed,
                                           None if cause == "none" else cause, mag,
                                           plant_seed=args.plant)
            t0 = time.perf_counter()
            doc = diagnose(with_history, day).to_json()
            rec = {"seed": seed, "cause": cause, "magnitude": mag,
                   "channel": day.effect.get("channel"), "named": doc["cause"],
                   "named_channel": doc["channel"],
                   "candidates": [[c["cause"], c["channel"], c["log_evidence"]]
                                  for c in doc["probabilities"]],
                   "cannot_tell": [c["cause"] for c in doc["cannot_tell"]],
                   "seconds": round(time.perf_counter() - t0, 1)}
            say(f"{cause} {mag} seed {seed}: named {doc['cause']} "
                f"({rec['seconds']} s)")
            days.append(rec)
            seed += 1
    return days


def true_index(rec: dict[str, Any]) -> int:
    """Index of the candidate that is right (cause, and channel of a sensor offset); -1
    when none is (an offset fitted on the other channel)."""
    for i, (c, ch, _) in enumerate(rec["candidates"]):
        if c == rec["cause"] and (c != "sensor_bias" or ch == rec["channel"]):
            return i
    return -1


def scores(days: list[dict[str, Any]], t: float) -> dict[str, float]:
    """Mean log loss, Brier score (over every candidate), top-1 and top-2 accuracy at ``t``."""
    ll, brier, top1, top2 = [], [], 0, 0
    for rec in days:
        L = np.array([c[2] for c in rec["candidates"]], float)
        p = softmax(L, t)
        i = true_index(rec)
        y = np.zeros_like(p)
        if i >= 0:
            y[i] = 1.0
        ll.append(-np.log(max(p[i], 1e-12)) if i >= 0 else np.log(1e12))
        brier.append(float(np.sum((p - y) ** 2)) + (1.0 if i < 0 else 0.0))
        order = np.argsort(-p, kind="stable")
        top1 += i >= 0 and order[0] == i
        top2 += i >= 0 and i in order[:2]
    n = max(len(days), 1)
    return {"log_loss": float(np.mean(ll)), "brier": float(np.mean(brier)),
            "top1": top1 / n, "top2": top2 / n}


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--plant", type=int, default=11)
    ap.add_argument("--history", type=int, default=4)
    ap.add_argument("--hours", type=float, default=16.0)
    ap.add_argument("--days-per-cause", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--refit", default=None, metavar="FILE")
    args = ap.parse_args()
    if args.refit:
        doc = json.loads(Path(args.refit).read_text())
        days = doc["days"]
    else:
        days = diagnose_days(args)
        doc = {"settings": vars(args), "days": days}
    usable = [(np.array([c[2] for c in r["candidates"]]), true_index(r)) for r in days]
    t = fit_temperature(usable)
    doc["fitted_temperature"] = t
    doc["at_fitted"] = scores(days, t)
    doc["at_module_temperature"] = {"temperature": TEMPERATURE, **scores(days, TEMPERATURE)}
    text = json.dumps(doc, indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(json.dumps({k: doc[k] for k in ("fitted_temperature", "at_fitted",
                                          "at_module_temperature")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
