"""Calibrate the diagnosis's probabilities on tuning days and check them on fresh ones
(issue 33 item 2, issue 39 items 2 and 3).

:mod:`softsensor.diagnosis.posterior` turns the candidates' log-evidences into
probabilities with a temperature and a contamination per kind of verdict; both are fitted
here, on tuning seeds only. One run diagnoses the days of one plant: independent plant
``--plant``, its normal learned from ``--history`` clean days (day seeds 100, 101, ...; as
``tests/diagnosis/test_diagnose_history.py`` does,
:func:`~softsensor.calibration.model_error_fit.fit_model_error` at the config's parameters),
then ``--days-per-cause`` test days per cause (day seeds 300, 301, ..., magnitudes one
uniform draw in each stratum of the effect's detectable range) diagnosed against it. It
stores per day the true cause, the verdict, every candidate's log-evidence and what they
were computed from (:func:`ingredients`), so that the probabilities can be fitted and judged
again without diagnosing (the expensive part: about 10 min per plant on this machine):

    python benchmarks/diagnosis_temperature.py --plant 11 --out plant11.json  # one plant
    python benchmarks/diagnosis_temperature.py --refit plant11.json plant12.json \
        --check plant7001.json plant7002.json plant7003.json --out result.json

The second form fits ``(T, eps)`` on the ``--refit`` (tuning) days
(:func:`~softsensor.diagnosis.posterior.fit_calibration`) and gives, on the tuning and on
the ``--check`` (fresh) days, at the fitted values, at the module's and at the settings
before issue 39 (``at_old_settings``: a plain softmax at ``T = 8``, "cannot tell" only
between two collinear extensions, applied to the same stored candidates: with the shapes,
the shapes scored at the old settings, not the diagnosis as it was before issue 39): the
Brier score, the days right and with the right cause in the top two, "cannot tell" counted
apart (days, how often the truth is in the pair, right when decided), the wrong verdicts
above 0.9, and the reliability tables (predicted probability against observed frequency,
over every candidate and over the verdicts). ``--occam`` tries a Laplace Occam factor for
each cause's size (:func:`with_occam`) in place of its Akaike charge.

Every figure is given twice: with each cause's shape on the residuals ranked with the
extensions (``shapes``, :mod:`softsensor.diagnosis.shapes`) and with the extensions alone
(``extensions_only``). ``--shapes FILE...`` adds the shapes to the days of earlier runs in
place (each day simulated again from its seeds, only the baseline and the shapes computed: a
few seconds a day), so that a change of the shapes is judged without diagnosing again:

    python benchmarks/diagnosis_temperature.py --shapes plant11.json plant12.json ...
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.diagnosis.posterior import (
    CANNOT_TELL_ODDS,
    CONTAMINATION,
    TEMPERATURE,
    brier,
    fit_calibration,
    kind,
    probabilities,
    undecided,
)

CAUSES = ("none", "inlet_moisture", "sensor_bias", "lab_delay", "fouling_drift", "input_lag",
          "ambient_heat_loss", "unexplained")


def say(msg: str) -> None:
    print(f"diagnosis_temperature: {msg}", file=sys.stderr, flush=True)


def plant_normal(plant: int, hours: float, history: int) -> tuple[Any, Any]:
    """``(config, config with the history's normal)`` of independent plant ``plant``: its
    normal learned from ``history`` clean days (day seeds 100, 101, ...)."""
    from softsensor.calibration.dataset import segment_from_day
    from softsensor.calibration.model_error_fit import fit_model_error
    from softsensor.calibration.params_file import params_document, write_params
    from softsensor.model.dryer import DryerModel
    from softsensor.plant.independent import simulate_independent_day
    from softsensor.plantconfig import load_parameters, load_plant_config

    cfg = load_plant_config()
    hist = [simulate_independent_day(cfg, hours, 100 + i, plant_seed=plant)
            for i in range(history)]
    segs = [segment_from_day(d, cfg, source=f"history {i}") for i, d in enumerate(hist)]
    me = fit_model_error(DryerModel(cfg), segs, cfg.parameter_vector(),
                         float(cfg.nominal.moisture_in))
    values = {n: cfg.parameters[n].value for n in cfg.parameters}
    with tempfile.TemporaryDirectory() as tmp:
        path = write_params(Path(tmp) / "params.toml",
                            params_document(cfg, values, {}, model_error=me.to_table()))
        return cfg, load_parameters(path, cfg)


def effect_days(cfg: Any, plant: int, hours: float, per_cause: int
              ) -> Iterator[tuple[str, float | None, int, Any]]:
    """``(cause, magnitude, day seed, day)`` of every test day (module docstring)."""
    from softsensor.plant.effects import EFFECTS
    from softsensor.plant.independent import simulate_independent_day

    rng = np.random.default_rng(plant)
    seed = 300
    for cause in CAUSES:
        if cause == "none":
            mags: list[float | None] = [None] * per_cause
        else:
            lo, hi = EFFECTS[cause].detectable
            mags = [float(lo + (hi - lo) * (j + rng.uniform()) / per_cause)
                    for j in range(per_cause)]
        for mag in mags:
            yield cause, mag, seed, simulate_independent_day(
                cfg, hours, seed, None if cause == "none" else cause, mag, plant_seed=plant)
            seed += 1


def diagnose_days(args: argparse.Namespace) -> list[dict[str, Any]]:
    from softsensor.diagnosis.diagnose_day import diagnose

    cfg, with_history = plant_normal(args.plant, args.hours, args.history)
    days = []
    for cause, mag, seed, day in effect_days(cfg, args.plant, args.hours, args.days_per_cause):
        t0 = time.perf_counter()
        diag = diagnose(with_history, day)
        doc = diag.to_json()
        rec = {"plant": args.plant, "seed": seed, "cause": cause, "magnitude": mag,
               "channel": day.effect.get("channel"), "named": doc["cause"],
               "named_channel": doc["channel"],
               "candidates": [[c["cause"], c["channel"], c["log_evidence"]]
                              for c in doc["probabilities"]],
               "cannot_tell": [c["cause"] for c in doc["cannot_tell"]],
               **extensions_only(diag),
               "seconds": round(time.perf_counter() - t0, 1), **ingredients(diag)}
        say(f"{cause} {mag} seed {seed}: named {doc['cause']} ({rec['seconds']} s)")
        days.append(rec)
        if args.out:  # what is done so far survives an interrupted run
            Path(args.out).write_text(json.dumps({"settings": vars(args), "days": days},
                                                 indent=1) + "\n")
    return days


def extensions_only(diag: Any) -> dict[str, Any]:
    """The day's candidates and named cause without the shapes (the extensions and the
    baseline alone), from which :func:`merged` ranks the shapes again."""
    from softsensor.diagnosis.posterior import log_evidence
    from softsensor.diagnosis.verdict import structure_margins, structured, verdict

    p = diag.problem
    margin = max((m for m, _, _ in structure_margins(p).values()), default=-math.inf)
    ev = log_evidence(diag.scores.values(), diag.skipped, margin)
    return {"candidates_extensions": [[c, ch, L] for c, ch, L, _ in ev],
            "named_extensions": verdict(list(diag.scores.values()), structured(p)).cause}


def add_shapes(path: str) -> None:
    """Each stored day of ``path`` (one plant's run) with every cause's shape on its
    residuals (:mod:`softsensor.diagnosis.shapes`, ``rec["shapes"]``), written back in
    place: the days are simulated again from their seeds and only the baseline and the
    shapes are computed (a few seconds a day, against half a minute for a diagnosis). The
    extensions' candidates stay as they were; :func:`_load` merges the shapes into them as
    :func:`~softsensor.diagnosis.posterior.log_evidence` does."""
    from softsensor.diagnosis.day_windows import day_windows
    from softsensor.diagnosis.problem import Problem, choose_split
    from softsensor.diagnosis.shapes import SHAPES
    from softsensor.estimation.settings import estimator_settings
    from softsensor.model.dryer import DryerModel

    doc = json.loads(Path(path).read_text())
    st = doc["settings"]
    cfg, normal = plant_normal(st["plant"], st["hours"], st["history"])
    model = DryerModel(normal)
    by_seed = {r["seed"]: r for r in doc["days"]}
    for cause, _, seed, day in effect_days(cfg, st["plant"], st["hours"], st["days_per_cause"]):
        rec = by_seed.get(seed)
        if rec is None or rec["cause"] != cause:
            continue
        w = day_windows(day, normal, "day")
        problem = Problem(normal, model, w, choose_split(w), model.theta0,
                          estimator_settings(normal).lab_std)
        rec["shapes"] = {sh.cause: sh.fit(problem).to_json() for sh in SHAPES}
        say(f"plant {st['plant']} seed {seed} {cause}: shapes "
            + ", ".join(f"{c} {f['log_bayes']}" for c, f in rec["shapes"].items()))
    Path(path).write_text(json.dumps(doc, indent=1) + "\n")


def ingredients(diag: Any) -> dict[str, Any]:
    """What the probabilities are computed from, so that another posterior can be tried on the
    stored days without diagnosing again (``--refit``): every score, the skipped causes, the
    structure margin, every signature's norm and the pairwise ``|cos|`` of the signatures and
    of each signature with the baseline's whitened residual."""
    from softsensor.diagnosis.detectability import collinearity
    from softsensor.diagnosis.verdict import structure_margins

    p = diag.problem
    resid = np.concatenate(p.whitened(p.baseline, "all"))
    sigs = diag.signatures
    names = sorted(sigs)
    margin = max((m for m, _, _ in structure_margins(p).values()), default=-np.inf)
    return {
        "shapes": {c: f.to_json() for c, f in diag.shapes.items()},
        "scores": [{"cause": s.cause, "channel": s.channel, "n_params": s.n_params,
                    "penalised": s.penalised, "eligible": bool(s.eligible), "gain": s.gain,
                    "loglik": s.loglik} for s in diag.scores.values()],
        "skipped": sorted(diag.skipped),
        "structure_margin": float(margin),
        "residual_norm": float(np.linalg.norm(resid)),
        "signatures": {c: {"channel": sigs[c].channel, "norm": sigs[c].norm,
                           "probe_size": sigs[c].probe_size, "n_params": sigs[c].n_params,
                           "residual_cos": (abs(float(sigs[c].vector @ resid))
                                            / (sigs[c].norm * float(np.linalg.norm(resid)))
                                            if sigs[c].norm > 0 and sigs[c].vector.shape
                                            == resid.shape and resid.any() else 0.0)}
                       for c in names},
        "collinearity": {f"{a}|{b}": collinearity(sigs[a], sigs[b])
                         for i, a in enumerate(names) for b in names[i + 1:]},
    }


def true_index(rec: dict[str, Any]) -> int:
    """Index of the candidate that is right (cause, and channel of a sensor offset); -1
    when none is (an offset fitted on the other channel)."""
    for i, (c, ch, _) in enumerate(rec["candidates"]):
        if c == rec["cause"] and (c != "sensor_bias" or ch == rec["channel"]):
            return i
    return -1


#: The contamination of the settings before issue 39 (a plain softmax at T = 8), applied
#: to the stored candidates (``at_old_settings``).
OLD_CONTAMINATION = {"extension": 0.0, "none": 0.0, "unexplained": 0.0}
#: Edges of the reliability table's bins of predicted probability.
BINS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.99, 1.0)


def _bin(p: float) -> int:
    return min(int(np.searchsorted(BINS, p, side="right")) - 1, len(BINS) - 2)


def _undecided(rec: dict[str, Any], p: np.ndarray, order: np.ndarray, t: float,
               old_rule: bool) -> list[str]:
    """The pair "cannot tell" names on this day (empty when it does not fire): the rule of
    :func:`~softsensor.diagnosis.posterior.cannot_tell`, or with ``old_rule`` the one it
    replaced (two extensions within the odds whose signatures have ``|cos| >= 0.9``)."""
    a, b = order[0], order[1]
    L = [c[2] for c in rec["candidates"]]
    if old_rule and (not p[b] > 0 or p[a] / p[b] > CANNOT_TELL_ODDS):
        return []
    if not old_rule and not undecided(L[a], L[b], t):
        return []
    ca, cb = rec["candidates"][a][0], rec["candidates"][b][0]
    if old_rule:
        cos = rec.get("collinearity", {})
        key = "|".join(sorted((ca, cb)))
        if key not in cos or cos[key] < 0.9:
            return []
    return [ca, cb]


def evaluate(days: list[dict[str, Any]], t: float, eps: dict[str, float],
             old_rule: bool = False) -> dict[str, Any]:
    """Brier score, right and top-two counts, "cannot tell" counted apart, wrong verdicts
    above 0.9, and the reliability table (every candidate of every day: predicted
    probability against how often it was the true one) at ``(t, eps)``."""
    br, right, top2, wrong_sure = [], 0, 0, []
    table = [[0, 0.0, 0] for _ in BINS[:-1]]
    verdicts = [[0, 0.0, 0] for _ in BINS[:-1]]
    told = {"days": 0, "true_in_pair": 0, "right_when_decided": 0, "decided": 0}
    for rec in days:
        L = np.array([c[2] for c in rec["candidates"]], float)
        p = probabilities(L, t, eps[kind(rec["named"])])
        i = true_index(rec)
        br.append(brier(p, i))
        order = np.argsort(-p, kind="stable")
        ok = bool(i >= 0 and order[0] == i)
        right += ok
        top2 += bool(i >= 0 and i in order[:2])
        if not ok and p[order[0]] > 0.9:
            wrong_sure.append({"plant": rec.get("plant"), "seed": rec["seed"],
                               "cause": rec["cause"],
                               "named": rec["candidates"][order[0]][0],
                               "probability": round(float(p[order[0]]), 3)})
        for j, q in enumerate(p):
            row = table[_bin(q)]
            row[0] += 1
            row[1] += float(q)
            row[2] += int(j == i)
        row = verdicts[_bin(p[order[0]])]
        row[0] += 1
        row[1] += float(p[order[0]])
        row[2] += int(ok)
        pair = _undecided(rec, p, order, t, old_rule)
        if pair:
            told["days"] += 1
            told["true_in_pair"] += rec["cause"] in pair
        else:
            told["decided"] += 1
            told["right_when_decided"] += ok

    def rows(tab: list[list[float]]) -> list[dict[str, Any]]:
        return [{"bin": f"{lo:g}-{hi:g}", "n": int(n),
                 "predicted": round(s / n, 3) if n else None,
                 "observed": round(k / n, 3) if n else None}
                for lo, hi, (n, s, k) in zip(BINS[:-1], BINS[1:], tab, strict=True)]

    return {"temperature": t, "contamination": eps, "days": len(days),
            "brier": round(float(np.mean(br)), 4), "right": right, "top_two": top2,
            "wrong_above_0.9": wrong_sure, "cannot_tell": told,
            "reliability_candidates": rows(table), "reliability_verdicts": rows(verdicts)}


def with_occam(rec: dict[str, Any]) -> dict[str, Any]:
    """``rec`` with each fitted cause's Akaike charge for its size (1 nat) replaced by a
    Laplace Occam factor: the size's prior uniform on [0, 2 x probe size], its posterior
    width from the curvature of the day's log-likelihood along the size, the signature's
    squared norm per probe size squared (:mod:`softsensor.diagnosis.detectability`), so the
    factor is ``log(sqrt(2 pi) / (2 |d|))``; causes without a signature are left as they
    are. The other parameters (onsets, time constants) keep their Akaike charge."""
    sigs = rec["signatures"]
    cands = []
    for c, ch, L in rec["candidates"]:
        n = sigs.get(c, {}).get("norm", 0.0)
        if n > 0:
            L = L + 1.0 + math.log(math.sqrt(2.0 * math.pi) / (2.0 * n))
        cands.append([c, ch, L])
    return dict(rec, candidates=cands)


def merged(rec: dict[str, Any]) -> dict[str, Any]:
    """``rec`` with its shapes (``rec["shapes"]``, :func:`add_shapes`) ranked with its
    candidates as :func:`~softsensor.diagnosis.posterior.with_shapes` ranks them, and the
    named cause the most probable candidate's."""
    from softsensor.diagnosis.posterior import with_shapes
    from softsensor.diagnosis.shapes import ShapeFit

    base, named = _extensions(rec)
    fits = [ShapeFit.from_json(f) for f in rec.get("shapes", {}).values()]
    cands = with_shapes([(c, ch, L, "") for c, ch, L in base], fits)
    top = max(range(len(cands)), key=lambda i: cands[i][2])
    named = cands[top][0] if cands[top][3] == "shape" else named
    return dict(rec, candidates=[[c, ch, L] for c, ch, L, _ in cands], named=named)


def _extensions(rec: dict[str, Any]) -> tuple[list[list[Any]], str]:
    """The day's candidates and named cause without the shapes (runs before the shapes
    stored only these, as ``candidates`` and ``named``)."""
    if "candidates_extensions" in rec:
        return rec["candidates_extensions"], rec["named_extensions"]
    return rec["candidates"], rec["named"]


def unmerged(rec: dict[str, Any]) -> dict[str, Any]:
    """``rec`` as the extensions alone rank it (:func:`_extensions`)."""
    cands, named = _extensions(rec)
    return dict(rec, candidates=cands, named=named)


def _load(paths: list[str], occam: bool = False, shapes: bool = True
          ) -> list[dict[str, Any]]:
    days = []
    for path in paths:
        days += json.loads(Path(path).read_text())["days"]
    days = [merged(r) if shapes else unmerged(r) for r in days]
    return [with_occam(r) for r in days] if occam else days


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--plant", type=int, default=11)
    ap.add_argument("--history", type=int, default=4)
    ap.add_argument("--hours", type=float, default=16.0)
    ap.add_argument("--days-per-cause", type=int, default=2)
    ap.add_argument("--out", default=None)
    ap.add_argument("--refit", nargs="+", default=None, metavar="FILE",
                    help="tuning days of earlier runs: fit on them without diagnosing")
    ap.add_argument("--check", nargs="*", default=(), metavar="FILE",
                    help="fresh days of earlier runs: judged at the fitted values")
    ap.add_argument("--occam", action="store_true",
                    help="try the Laplace Occam factor for each cause's size (with_occam)")
    ap.add_argument("--shapes", nargs="+", default=None, metavar="FILE",
                    help="add every cause's shape to the days of earlier runs (in place)")
    args = ap.parse_args()
    if args.shapes:
        for path in args.shapes:
            add_shapes(path)
        return 0
    if not args.refit:
        days = diagnose_days(args)
        doc: dict[str, Any] = {"settings": vars(args), "days": days}
        text = json.dumps(doc, indent=1)
        if args.out:
            Path(args.out).write_text(text + "\n")
        print(json.dumps(evaluate(days, TEMPERATURE, CONTAMINATION), indent=1))
        return 0
    doc = {"tuning_files": args.refit, "fresh_files": list(args.check), "occam": args.occam,
           "module": {"temperature": TEMPERATURE, "contamination": CONTAMINATION}}
    # with every cause's shape (:mod:`softsensor.diagnosis.shapes`) ranked with the
    # extensions, and without (the extensions alone, as before the shapes)
    for key, shapes in (("shapes", True), ("extensions_only", False)):
        tuning = _load(args.refit, args.occam, shapes)
        fresh = _load(list(args.check), args.occam, shapes)
        t, eps = fit_calibration([(np.array([c[2] for c in r["candidates"]]), true_index(r),
                                   kind(r["named"])) for r in tuning])
        # a kind the tuning days never named keeps the module's value
        eps = {**CONTAMINATION, **eps}
        doc[key] = {
            "fitted": {"temperature": t, "contamination": eps},
            "tuning": {"fitted": evaluate(tuning, t, eps),
                       "module": evaluate(tuning, TEMPERATURE, CONTAMINATION),
                       "at_old_settings": evaluate(tuning, 8.0, OLD_CONTAMINATION,
                                                   old_rule=True)},
            "fresh": {"fitted": evaluate(fresh, t, eps),
                      "module": evaluate(fresh, TEMPERATURE, CONTAMINATION),
                      "at_old_settings": evaluate(fresh, 8.0, OLD_CONTAMINATION,
                                                  old_rule=True)}
            if fresh else None}
    text = json.dumps(doc, indent=1)
    if args.out:
        Path(args.out).write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
