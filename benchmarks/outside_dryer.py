"""The sister dryer: the user's path on recordings of a dryer nobody on the project tuned for.

``../shared/outside-dryer`` (beside the project) holds 48 h periods of a second dryer simulated
apart from softsensor: ``history/`` before the sensor is installed, ``recent/`` after. There is
no truth: the lab results are the only reference. This benchmark does what its README says a
plant engineer would do, with the ``softsensor`` command itself (a subprocess per verb, the
defaults first):

1. ``softsensor calibrate history/*.mcap`` (structure search included), timed;
2. ``softsensor replay recent/*.mcap`` in time order, one stream, the state carried from one
   period to the next; and the same with ``--estimator openloop`` (the model alone, no labs);
3. every lab result of ``recent/`` scored against what each method published **before the
   result arrived**: the sensor's estimate for the window holding the sample time (the
   published outlet moisture, and the physics' own ``moisture_out_physics`` beside it), and,
   at that estimate's publication time, knowing only the results arrived by then:

   * **hold**: the latest arrived result (by sample time), held;
   * **regression**: the spreadsheet regression the README names, a linear fit of the lab on
     the 600 s means of the scan signals (:func:`softsensor.estimation.lab_regression
     .fit_lab_regression`) fitted on the labs of ``history/``, plus the mean residual of the
     last three arrived results;
   * **model alone**: the open-loop replay's estimate for the window.

   RMSE against the labs (which carry the lab's own noise, about 0.003 kg/kg), the share of
   labs inside the sensor's 95 % band (``moisture_out +- 1.96 moisture_out_std``), the ratio to
   the better peer, per period and pooled; the inlet-moisture estimate's range per period.
   Labs before any method has a value (the first arrivals after installation, when holding has
   nothing to hold) are scored for the sensor and reported apart (``first_labs``).
4. with ``--parts ...,verdicts``: ``softsensor diagnose`` and ``softsensor validate`` on each
   recent period with the calibration, their headline and named cause.

It is a check, never tuning data: no default, threshold or constant is set from these files.

    python benchmarks/outside_dryer.py [--data ../shared/outside-dryer] [--work DIR]
        [--params PARAMS.toml] [--parts calibrate,sensor,verdicts] [--out FILE] [--label L]

``--params`` skips step 1 with a calibration made before (its JSON beside it as
``calibration.json`` is quoted when present). Output: one JSON document on stdout (and
``--out``), progress on stderr. A default run takes about 15 min on two quiet cores
(calibration 4 to 10 min, two replays of 16 days, the scoring in seconds).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import provenance  # noqa: E402

from softsensor.estimation.lab_regression import (  # noqa: E402
    LabRegression,
    at_windows,
    fit_lab_regression,
    lab_features,
    window_means,
)
from softsensor.recording.mcap_day import iter_messages, read_day  # noqa: E402
from softsensor.signals import TOPIC_ESTIMATE  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
#: The README's regression updates its bias by the mean residual of this many last labs.
BIAS_LABS = 3
#: The band's half width in standard deviations (a 95 % normal band, as published).
Z95 = 1.96


def say(msg: str) -> None:
    print(f"[outside_dryer] {msg}", file=sys.stderr, flush=True)


def softsensor_cmd() -> list[str]:
    exe = Path(sys.executable).with_name("softsensor")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "softsensor.cli"]


def run_verb(args: Sequence[str], log: Path) -> tuple[int, float, str]:
    """Run ``softsensor ARGS``; its exit status, wall seconds and last stderr line."""
    t0 = time.perf_counter()
    with open(log, "w") as err:
        proc = subprocess.run([*softsensor_cmd(), *args], stdout=subprocess.PIPE,
                              stderr=err, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    lines = [s for s in log.read_text().splitlines() if s.strip()]
    if proc.stdout:
        log.with_suffix(".stdout").write_text(proc.stdout)
    return proc.returncode, wall, lines[-1] if lines else ""


def estimates(path: Path) -> pd.DataFrame:
    """One row per published estimate: window, log time, moisture out/in and their sds, the
    physics' own outlet moisture."""
    rows = []
    for _topic, t, b in iter_messages(path, topics=[TOPIC_ESTIMATE]):
        blend = b.get("blend") or {}
        rows.append({"log_time_ns": t, "start": b["window_start_ns"], "end": b["window_end_ns"],
                     "moisture_out": b.get("moisture_out"),
                     "moisture_out_std": b.get("moisture_out_std"),
                     "moisture_in": b.get("moisture_in"),
                     "moisture_in_std": b.get("moisture_in_std"),
                     "physics": blend.get("moisture_out_physics", b.get("moisture_out"))})
    return pd.DataFrame(rows).astype(float).astype({"log_time_ns": np.int64, "start": np.int64,
                                                    "end": np.int64})


def published_before(est: pd.DataFrame, sample_ns: int, arrival_ns: int) -> pd.Series | None:
    """The estimate for the window holding ``sample_ns`` if it was published before the
    result arrived, else the latest one published before then; None when none was."""
    hit = est[(est["start"] < sample_ns) & (est["end"] >= sample_ns)
              & (est["log_time_ns"] < arrival_ns)]
    if len(hit):
        return hit.iloc[-1]
    before = est[est["log_time_ns"] < arrival_ns]
    return before.iloc[-1] if len(before) else None


def regression_rows(reg: LabRegression, days: Sequence[Any]) -> pd.DataFrame:
    """Every recent lab with its period, sample and arrival times and the regression at its
    sample time (without the bias update)."""
    out = []
    for k, d in enumerate(days):
        labs = d.labs.sort_values(["log_time_ns", "sample_id"])
        wm = window_means(d.scans)[list(reg.signals)]
        pred = reg.predict(at_windows(wm, labs["sample_time_ns"].to_numpy(np.int64)))
        for (_, r), p in zip(labs.iterrows(), pred, strict=True):
            out.append({"period": k, "sample_ns": int(r["sample_time_ns"]),
                        "arrival_ns": int(r["log_time_ns"]), "lab": float(r["moisture_out"]),
                        "reg_raw": float(p)})
    return pd.DataFrame(out).sort_values(["arrival_ns", "sample_ns"]).reset_index(drop=True)


def score_labs(labs: pd.DataFrame, est: pd.DataFrame, openloop: pd.DataFrame | None
               ) -> pd.DataFrame:
    """Each lab with what every method published before it arrived (module docstring)."""
    rows = []
    for _, r in labs.iterrows():
        e = published_before(est, r["sample_ns"], r["arrival_ns"])
        tau = int(e["log_time_ns"]) if e is not None else int(r["arrival_ns"]) - 1
        known = labs[labs["arrival_ns"] <= tau]
        hold = (float(known.sort_values("sample_ns")["lab"].iloc[-1]) if len(known)
                else math.nan)
        last = known.tail(BIAS_LABS)
        bias = float((last["lab"] - last["reg_raw"]).mean()) if len(last) else 0.0
        o = None if openloop is None else published_before(openloop, r["sample_ns"],
                                                           r["arrival_ns"])
        rows.append({**r.to_dict(),
                     "sensor": math.nan if e is None else e["moisture_out"],
                     "sensor_std": math.nan if e is None else e["moisture_out_std"],
                     "physics": math.nan if e is None else e["physics"],
                     "hold": hold, "regression": r["reg_raw"] + bias,
                     "regression_updated": len(last) > 0,
                     "model_alone": math.nan if o is None else o["moisture_out"]})
    return pd.DataFrame(rows)


METHODS = ("sensor", "physics", "hold", "regression", "model_alone")


def rmse(e: np.ndarray) -> float:
    e = np.asarray(e, float)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2))) if len(e) else math.nan


def summarise(s: pd.DataFrame) -> dict[str, Any]:
    """RMSE of each method against the labs, band coverage, the ratio to the better peer."""
    out: dict[str, Any] = {"n_labs": len(s)}
    for m in METHODS:
        out[f"rmse_{m}"] = rmse(s[m] - s["lab"])
    inside = (s["lab"] - s["sensor"]).abs() <= Z95 * s["sensor_std"]
    out["band_coverage"] = float(inside[np.isfinite(s["sensor_std"])].mean()) if len(s) else None
    better = min(out["rmse_hold"], out["rmse_regression"])
    out["ratio_to_better_peer"] = out["rmse_sensor"] / better if better > 0 else math.nan
    out["better_peer"] = "hold" if out["rmse_hold"] <= out["rmse_regression"] else "regression"
    return out


def sensor_part(data: Path, work: Path, params: Path, reg: LabRegression) -> dict[str, Any]:
    recent = sorted((data / "recent").glob("*.mcap"))
    out: dict[str, Any] = {"periods": [p.name for p in recent]}
    for name, extra in (("estimates", []), ("openloop", ["--estimator", "openloop"])):
        dest = work / f"{name}.mcap"
        say(f"replay {len(recent)} recent periods ({name})")
        code, wall, last = run_verb(["replay", *map(str, recent), "--params", str(params),
                                     "--out", str(dest), "--quiet", *extra],
                                    work / f"replay_{name}.log")
        out[f"replay_{name}"] = {"exit": code, "wall_s": round(wall, 1), "last_line": last}
        if code != 0:
            raise SystemExit(f"replay ({name}) exited {code}: {last}")
    est = estimates(work / "estimates.mcap")
    ol = estimates(work / "openloop.mcap")
    days = [read_day(p) for p in recent]
    labs = regression_rows(reg, days)
    s = score_labs(labs, est, ol)
    s.to_csv(work / "labs_scored.csv", index=False)
    scored = s[np.isfinite(s["hold"])]
    out["pooled"] = summarise(scored)
    out["first_labs"] = summarise(s[~np.isfinite(s["hold"])])
    out["per_period"] = []
    for k, p in enumerate(recent):
        d = summarise(scored[scored["period"] == k])
        e = est[(est["end"] > days[k].scans.index[0]) & (est["end"] <= days[k].scans.index[-1])]
        d.update(period=p.name, moisture_in_min=float(e["moisture_in"].min()),
                 moisture_in_mean=float(e["moisture_in"].mean()),
                 moisture_in_max=float(e["moisture_in"].max()))
        out["per_period"].append(d)
    pp = out["per_period"]
    out["periods_below_both_peers"] = sum(
        d["rmse_sensor"] < min(d["rmse_hold"], d["rmse_regression"]) for d in pp)
    return out


def verdicts_part(data: Path, work: Path, params: Path) -> list[dict[str, Any]]:
    out = []
    for p in sorted((data / "recent").glob("*.mcap")):
        rec: dict[str, Any] = {"period": p.name}
        for verb in ("diagnose", "validate"):
            say(f"{verb} {p.name}")
            log = work / f"{verb}_{p.stem}.log"
            code, wall, last = run_verb([verb, str(p), "--params", str(params)], log)
            rec[verb] = {"exit": code, "wall_s": round(wall, 1), "headline": last}
            stdout = log.with_suffix(".stdout")
            if stdout.exists():
                try:
                    doc = json.loads(stdout.read_text())
                except json.JSONDecodeError:
                    doc = None
                if verb == "diagnose" and isinstance(doc, dict):
                    rec[verb]["cause"] = doc.get("cause")
                    rec[verb]["probability"] = doc.get("probability")
        out.append(rec)
    return out


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "outside-dryer",
                    help="the sister dryer's folder (history/ and recent/)")
    ap.add_argument("--work", type=Path, default=None,
                    help="folder for the calibration, replays and logs (default: a temporary "
                         "one under /tmp)")
    ap.add_argument("--params", type=Path, default=None,
                    help="use this calibration instead of running `calibrate` on history/")
    ap.add_argument("--parts", default="calibrate,sensor",
                    help="comma list of calibrate, sensor, verdicts")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    ap.add_argument("--label", default=None, help="a name for this run in the JSON")
    return ap.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    a = parse_args(argv)
    if not (a.data / "history").is_dir() or not (a.data / "recent").is_dir():
        print(f"outside_dryer: {a.data} has no history/ and recent/ folders", file=sys.stderr)
        return 2
    work = a.work or Path(f"/tmp/outside_dryer_{int(time.time())}")
    work.mkdir(parents=True, exist_ok=True)
    parts = {p.strip() for p in a.parts.split(",") if p.strip()}
    doc: dict[str, Any] = {"label": a.label, "commit": provenance.commit(),
                           "machine": provenance.machine(), "command": " ".join(sys.argv),
                           "data": str(a.data), "work": str(work)}
    history = sorted((a.data / "history").glob("*.mcap"))
    params = work / "params.toml"
    if a.params is not None:
        if a.params.resolve() != params.resolve():
            shutil.copy(a.params, params)
        cj = a.params.with_name("calibration.json")
        doc["calibration"] = {"params": str(a.params), "reused": True}
        if cj.exists():
            doc["calibration"]["json"] = json.loads(cj.read_text())
    elif "calibrate" in parts:
        say(f"calibrate on {len(history)} history periods")
        code, wall, last = run_verb(["calibrate", *map(str, history), "--out", str(params),
                                     "--json", str(work / "calibration.json"), "--quiet"],
                                    work / "calibrate.log")
        doc["calibration"] = {"exit": code, "wall_s": round(wall, 1), "last_line": last}
        if code != 0:
            print(json.dumps(doc, indent=1))
            return 1
        doc["calibration"]["json"] = json.loads((work / "calibration.json").read_text())
    else:
        raise SystemExit("outside_dryer: no calibration: give --params or the calibrate part")
    say("fit the spreadsheet regression on the history's labs")
    reg = fit_lab_regression([lab_features(d.scans, d.labs) for d in map(read_day, history)])
    if "sensor" in parts:
        doc["sensor"] = sensor_part(a.data, work, params, reg)
        p = doc["sensor"]["pooled"]
        say(f"pooled on {p['n_labs']} labs: sensor {p['rmse_sensor']:.4f}, physics "
            f"{p['rmse_physics']:.4f}, hold {p['rmse_hold']:.4f}, regression "
            f"{p['rmse_regression']:.4f}, model alone {p['rmse_model_alone']:.4f} kg/kg; "
            f"band {p['band_coverage']:.0%}; ratio to the better peer "
            f"{p['ratio_to_better_peer']:.2f}")
    if "verdicts" in parts:
        doc["verdicts"] = verdicts_part(a.data, work, params)
    text = json.dumps(doc, indent=1, default=float)
    print(text)
    if a.out is not None:
        a.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
