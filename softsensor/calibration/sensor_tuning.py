"""What the sensor learns of its own plant from the history: its noise and its blend.

The filter's noise model and the weighing of its sources
(:mod:`softsensor.estimation.peer_blend`: the physics, the held lab, the lab regression)
describe a plant: how fast its
inlet moisture wanders, how much of an air-temperature move its thermometers lag, how much the
physics, the regression and the last lab are each worth at the next lab result. Shipped
constants sized on one plant do not carry to another (the sister dryer: the regression beat a
sensor weighted 0.9 on its physics). Here they are learned from the plant's own history, as
the calibration's last step, on the days the sensor will continue from:

1. **the filter's noise** (:data:`NOISE_KEYS`): the maximum of the filter's prequential lab
   likelihood (each lab result's log density under the estimate the filter had published for
   its sample window before the result arrived, :mod:`.sensor_score`; the prediction-error
   method of CTSM, Kristensen, Madsen and Jørgensen, Automatica 40:225, 2004, on the
   innovations that matter here), with a log-normal prior around the shipped values
   (:data:`PRIOR_SD`), by a coordinate search in log space; each value's standard error from
   the curvature of the search's last three points (in log space, as a factor);
2. **the blend** (:data:`BLEND_KEYS`): the prior weights of the three sources, the memory of
   their evidence and its tempering, chosen on the same days by the squared error of the
   published estimate at each lab before it arrived (stacking of predictive means, Yao et al.,
   Bayesian Analysis 13:917, 2018; the dynamic evidence on top is the bounded refinement),
   with the regression refitted without the day it predicts (out of fold); the physics' run
   does not depend on the blend, so every candidate is one cheap replay of
   :func:`~softsensor.estimation.peer_blend.advance` over the recorded ticks.

**Day-disjoint check.** Each part is learned again leaving each scored day out and scored on
that day (leave one day out): the learned settings are deployed only when their held-out score
is no worse than the shipped ones' (the noise: the held-out lab log density; the blend: the
held-out RMSE); otherwise the shipped values stay, and the table says why. The learned values
go to PARAMS.toml's ``[sensor]`` (:meth:`SensorTuning.to_table`), whose ``values`` the
estimator reads in place of the shipped ``[estimator]`` defaults
(:func:`softsensor.plantconfig.load_parameters`; a key the plant config sets itself wins).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.calibration.dataset import Segment
from softsensor.calibration.sensor_score import DELAY_TICKS, DayRun, filter_day
from softsensor.errors import ConfigError
from softsensor.estimation import peer_blend
from softsensor.estimation.lab_regression import LabRegression, fit_lab_regression
from softsensor.estimation.settings import EstimatorSettings, estimator_settings
from softsensor.plantconfig import PlantConfig, load_parameters

#: Latest days of the history the sensor is tuned on (48 h each: about 10 s of filtering
#: apiece on one core).
TUNING_DAYS = 4
#: The filter's constants learned (each a rate or a share of the plant's, positive).
NOISE_KEYS: tuple[str, ...] = ("moisture_in_walk", "inlet_gain_walk", "transient_fraction")
#: Standard deviation of the log-normal prior around the shipped value (ln 4: a plant whose
#: constant is 4 times the shipped one is one sd away, and the labs of a few days move it).
PRIOR_SD = math.log(4.0)
#: Factors of the coordinate search, coarse to fine (one pass of 3: each filter run of the
#: tuning days costs seconds, and the prior's ln 4 says a factor of 3 is a real move).
SEARCH_FACTORS: tuple[float, ...] = (3.0,)
#: The blend's keys and their candidate values (physics' prior weight, the hold's, the
#: evidence's memory per lab result and its tempering; the regression takes the rest).
BLEND_KEYS: tuple[str, ...] = ("peer_prior_physics", "peer_prior_hold", "peer_forgetting",
                               "peer_evidence")
BLEND_PHYSICS: tuple[float, ...] = (0.1, 0.25, 0.4, 0.55, 0.7, 0.85, 0.95)
BLEND_HOLD: tuple[float, ...] = (0.0, 0.1, 0.25)
BLEND_FORGETTING: tuple[float, ...] = (0.7, 0.85, 0.95)
BLEND_EVIDENCE: tuple[float, ...] = (0.0, 0.5, 1.0)


@dataclass(frozen=True)
class SensorTuning:
    """What :func:`tune_sensor` learned: ``values`` deployed (the ``[estimator]`` keys),
    ``shipped`` (what they replace), ``standard_error`` (per noise key, a factor in log space),
    ``check`` (the held-out scores of learned and shipped, per part), ``deployed`` per part
    (``"learned"`` or ``"shipped"`` and why), ``days`` and ``labs`` scored."""

    values: dict[str, float]
    shipped: dict[str, float]
    standard_error: dict[str, float]
    check: dict[str, dict[str, float]]
    deployed: dict[str, str]
    days: int
    labs: int

    def to_table(self) -> dict[str, Any]:
        """PARAMS.toml's ``[sensor]``."""
        return {"days": self.days, "labs": self.labs, "values": dict(self.values),
                "shipped": dict(self.shipped), "standard_error": dict(self.standard_error),
                "check": {k: dict(v) for k, v in self.check.items()},
                "deployed": dict(self.deployed)}


# ------------------------------------------------------------------------------ the blend
def blend_errors(run: DayRun, s: EstimatorSettings) -> np.ndarray:
    """The published blend's error (lab minus estimate) at every lab result of ``run`` that
    had an estimate, as published for the lab's sample window before the result was known:
    the blend's state carries the results sampled in earlier windows (the filter's run hands
    them over :data:`~.sensor_score.DELAY_TICKS` after their window, the same)."""
    reg = run.regression
    state = peer_blend.fresh(s, reg)
    errs: list[float] = []
    by_window: dict[int, list[Any]] = {}
    for lab, k in zip(run.labs, run.lab_window, strict=True):
        by_window.setdefault(int(k), []).append(lab)
    for k in sorted(by_window):
        prev = run.physics[k - 1] if k > 0 else None
        state["physics"] = None if prev is None else [float(prev[0]), float(prev[1])]
        phys = run.physics[k] or (None, None)
        window = run.windows[k]
        _, _, mix = peer_blend.advance(s, reg, state, window, (), phys)
        labs = tuple(by_window[k])
        if mix is not None:
            errs.extend(lab.moisture_out - mix[0] for lab in labs)
        state, _, _ = peer_blend.advance(s, reg, state, window, labs, phys)
    return np.asarray(errs, float)


def blend_candidates(s: EstimatorSettings, with_regression: bool) -> list[EstimatorSettings]:
    """Every candidate of the blend's grid (module docstring); without a regression the hold
    takes what the physics leaves."""
    out = []
    holds = BLEND_HOLD if with_regression else (None,)
    for p, h, f, e in itertools.product(BLEND_PHYSICS, holds, BLEND_FORGETTING,
                                        BLEND_EVIDENCE):
        if h is not None and p + h > 1.0 - 1e-9:
            continue
        out.append(replace(s, peer_prior_physics=p, peer_prior_hold=h, peer_forgetting=f,
                           peer_evidence=e))
    return out


def _sse_table(runs: Sequence[DayRun], cands: Sequence[EstimatorSettings]
               ) -> tuple[np.ndarray, np.ndarray]:
    """Sum of squared errors and count per (candidate, day)."""
    sse = np.zeros((len(cands), len(runs)))
    n = np.zeros((len(cands), len(runs)))
    for i, c in enumerate(cands):
        for d, run in enumerate(runs):
            e = blend_errors(run, c)
            sse[i, d], n[i, d] = float(np.sum(e**2)), e.size
    return sse, n


def fit_blend(runs: Sequence[DayRun], s: EstimatorSettings
              ) -> tuple[EstimatorSettings, dict[str, float], str]:
    """The blend's candidate with the least squared error on ``runs``, its held-out check
    (leave one day out: each day scored by the candidate the other days chose) beside the
    shipped settings', and the verdict: learned only when the held-out RMSE is no worse."""
    with_reg = any(r.regression is not None for r in runs)
    cands = [s, *blend_candidates(s, with_reg)]
    sse, n = _sse_table(runs, cands)

    def rmse(i: int, days: np.ndarray) -> float:
        k = float(n[i, days].sum())
        return math.sqrt(float(sse[i, days].sum()) / k) if k else math.inf

    every = np.arange(len(runs))
    best = int(np.argmin([rmse(i, every) for i in range(len(cands))]))
    held_sse, held_n = 0.0, 0.0
    for d in range(len(runs)):
        rest = np.delete(every, d)
        pick = int(np.argmin([rmse(i, rest) for i in range(len(cands))])) if rest.size else 0
        held_sse += float(sse[pick, d])
        held_n += float(n[pick, d])
    shipped_held = rmse(0, every)
    learned_held = math.sqrt(held_sse / held_n) if held_n else math.inf
    check = {"rmse_learned_in_sample": rmse(best, every),
             "rmse_learned_held_out": learned_held, "rmse_shipped": shipped_held,
             "labs": float(n[0].sum())}
    if learned_held <= shipped_held:
        return cands[best], check, "learned: its held-out RMSE is no worse than the shipped"
    return s, check, "shipped: the learned blend predicted the held-out days' labs worse"


# ------------------------------------------------------------------------------ the noise
def _log_score(runs: Sequence[DayRun]) -> tuple[float, int]:
    """Sum of the physics' lab log densities over ``runs`` and their count."""
    v = [x for r in runs for x in r.log_density if x is not None]
    return float(np.sum(v)), len(v)


def fit_noise(run_days: Callable[[EstimatorSettings], list[DayRun]], s: EstimatorSettings,
              keys: Sequence[str] = NOISE_KEYS
              ) -> tuple[EstimatorSettings, dict[str, float], list[DayRun]]:
    """The maximum a posteriori of the filter's lab log score over ``keys`` (coordinate
    search in log space, :data:`SEARCH_FACTORS`, the prior :data:`PRIOR_SD` around the
    shipped values); ``run_days(settings)`` filters the tuning days. Returns the settings,
    each key's standard error (a factor) and the days' runs at the optimum."""
    keys = [k for k in keys if float(getattr(s, k)) > 0]  # a constant turned off stays off
    shipped = {k: float(getattr(s, k)) for k in keys}
    cache: dict[tuple[float, ...], tuple[float, list[DayRun]]] = {}

    def objective(vals: Mapping[str, float]) -> tuple[float, list[DayRun]]:
        key = tuple(round(math.log(vals[k]), 9) for k in keys)
        if key not in cache:
            runs = run_days(replace(s, **vals))
            total, _ = _log_score(runs)
            prior = sum(0.5 * (math.log(vals[k] / shipped[k]) / PRIOR_SD) ** 2 for k in keys)
            cache[key] = (total - prior, runs)
        return cache[key]

    cur = dict(shipped)
    best, runs = objective(cur)
    curvature: dict[str, tuple[float, float, float, float]] = {}
    for factor in SEARCH_FACTORS:
        for k in keys:
            trial = [{**cur, k: cur[k] * f} for f in (factor, 1.0 / factor)]
            scores = [objective(t) for t in trial]
            up, down = scores[0][0], scores[1][0]
            curvature[k] = (down, best, up, math.log(factor))
            j = int(np.argmax([up, down]))
            if scores[j][0] > best:
                cur, (best, runs) = trial[j], scores[j]
    se = {}
    for k, (lo, mid, hi, h) in curvature.items():
        second = (hi - 2 * mid + lo) / (h * h)  # d2/d(ln v)2 of the log posterior
        se[k] = math.exp(math.sqrt(-1.0 / second)) if second < 0 else math.inf
    return replace(s, **cur), se, runs


# ------------------------------------------------------------------------------ the front
def _regressions(lab_rows: Sequence[tuple[np.ndarray, np.ndarray]] | None,
                 scored: Sequence[int], signals: Sequence[str] | None
                 ) -> list[LabRegression | None]:
    """Per scored day, the lab regression fitted on every other day of the history (out of
    fold); None without rows or with too few labs."""
    out: list[LabRegression | None] = []
    for d in scored:
        if lab_rows is None or signals is None:
            out.append(None)
            continue
        rest = [r for i, r in enumerate(lab_rows) if i != d and len(r[1])]
        try:
            out.append(fit_lab_regression(rest, signals))
        except ConfigError:  # too few labs without that day: the blend runs without it
            out.append(None)
    return out


def tune_sensor(config: PlantConfig, days: Sequence[Segment],
                lab_rows: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
                signals: Sequence[str] | None = None, *, n_days: int = TUNING_DAYS,
                noise: bool = True, workers: int = 2,
                say: Callable[[str], None] | None = None) -> SensorTuning:
    """Learn the sensor's noise and blend on the latest ``n_days`` of ``days`` (module
    docstring). ``config``: as PARAMS.toml deploys it (parameters, structure, model error,
    regression); ``lab_rows``: per day of ``days``, the regression's rows
    (:func:`~softsensor.estimation.lab_regression.lab_features` on ``signals``), for the
    out-of-fold regressions; ``noise``: learn the filter's noise too (else the blend only).

    The noise is searched on the older half of the tuning days and checked on the newer
    half (day-disjoint: the filter starts afresh each day); the blend is chosen on all of
    them at the noise deployed and checked leaving one day out."""
    say = say or (lambda msg: None)
    s0 = replace(estimator_settings(config), peer_blend=False, band_conformal=False)
    order = sorted(range(len(days)), key=lambda i: days[i].start_ns)
    scored = order[-n_days:]
    regs = dict(zip(scored, _regressions(lab_rows, scored, signals), strict=True))

    def run_days(s: EstimatorSettings, which: Sequence[int]) -> list[DayRun]:
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            return list(pool.map(lambda i: filter_day(config, days[i], s, DELAY_TICKS,
                                                      regs[i]), which))

    shipped = {k: float(getattr(s0, k)) for k in NOISE_KEYS}
    check: dict[str, dict[str, float]] = {}
    deployed: dict[str, str] = {}
    se: dict[str, float] = {}
    runs: list[DayRun] | None = None
    s1 = s0
    if noise and len(scored) >= 2:
        fit_on, check_on = scored[:len(scored) // 2], scored[len(scored) // 2:]
        say(f"sensor noise: searched on {len(fit_on)} days, checked on {len(check_on)}")
        fit_runs: dict[EstimatorSettings, list[DayRun]] = {}

        def on_fit_days(s: EstimatorSettings) -> list[DayRun]:
            fit_runs[s] = run_days(s, fit_on)
            return fit_runs[s]

        learned, se, _ = fit_noise(on_fit_days, s0)
        base_check = run_days(s0, check_on)
        new_check = base_check if learned == s0 else run_days(learned, check_on)
        check["noise"], deployed["noise"] = _noise_check(base_check, new_check, s0, learned)
        if deployed["noise"].startswith("learned"):
            s1 = learned
        # the blend is chosen on every tuning day at the noise deployed: runs already made
        runs = [*fit_runs[s1], *(new_check if s1 is learned else base_check)]
    say("sensor blend")
    runs = runs if runs is not None else run_days(s1, scored)
    blend_shipped = replace(s1, peer_blend=True)
    s2, check["blend"], deployed["blend"] = fit_blend(runs, blend_shipped)
    keys = (NOISE_KEYS if deployed.get("noise", "").startswith("learned") else ()) + (
        BLEND_KEYS if deployed["blend"].startswith("learned") else ())
    values = {k: getattr(s2, k) for k in keys if getattr(s2, k) is not None}
    ship = {**shipped, **{k: getattr(blend_shipped, k) for k in BLEND_KEYS}}
    return SensorTuning(values={k: float(v) for k, v in values.items()},
                        shipped={k: float(v) for k, v in ship.items() if v is not None},
                        standard_error=se, check=check, deployed=deployed,
                        days=len(scored), labs=int(check["blend"]["labs"]))


def tune_deployed(params: str | Path, base: PlantConfig, days: Sequence[Segment],
                  lab_rows: Sequence[tuple[np.ndarray, np.ndarray]] | None,
                  regression: LabRegression | None,
                  say: Callable[[str], None] | None = None) -> SensorTuning:
    """:func:`tune_sensor` on the calibration just written to ``params`` (read back as the
    estimator will read it, on ``base``)."""
    config = load_parameters(params, base)
    return tune_sensor(config, days, lab_rows,
                       None if regression is None else regression.signals, say=say)


def _noise_check(base: Sequence[DayRun], learned: Sequence[DayRun], s0: EstimatorSettings,
                 s1: EstimatorSettings) -> tuple[dict[str, float], str]:
    """The learned noise against the shipped on the same days, per day (each day's labs
    scored by the filter, which starts afresh every day: the days are disjoint runs), and the
    verdict: learned when the mean log density is higher on at least half the days and in
    all (a noise that wins on one day by luck and loses on the rest is not the plant's)."""
    per = []
    for a, b in zip(base, learned, strict=True):
        la, na = _log_score([a])
        lb, nb = _log_score([b])
        if na and nb:
            per.append(lb / nb - la / na)
    total_a, n_a = _log_score(base)
    total_b, n_b = _log_score(learned)
    check = {"log_score_shipped": total_a / n_a if n_a else -math.inf,
             "log_score_learned": total_b / n_b if n_b else -math.inf,
             "days_better": float(sum(p > 0 for p in per)), "days": float(len(per))}
    if s1 == s0:
        return check, "shipped: the search stayed at the shipped values"
    if per and check["log_score_learned"] >= check["log_score_shipped"] and \
            2 * check["days_better"] >= len(per):
        return check, "learned: a higher lab log score on the tuning days, on half of them or more"
    return check, "shipped: the learned noise scored the tuning days' labs no better"


__all__ = ["BLEND_KEYS", "NOISE_KEYS", "PRIOR_SD", "TUNING_DAYS", "SensorTuning",
           "blend_candidates", "blend_errors", "fit_blend", "fit_noise",
           "tune_deployed", "tune_sensor"]
