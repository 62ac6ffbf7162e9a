"""The plant's own normal verdicts: what the diagnosis and the validation say of its healthy
history days, each judged against a normal that did not see it.

A log-evidence of the diagnosis (:mod:`.posterior`) is a Bayes factor only where the model
and its normal (:mod:`.calibration_error`) are right. On a real dryer they are not, and how
far each candidate's evidence reaches on a day with nothing wrong is a fact about that
plant, not about the virtual plant the constants of :mod:`.posterior` were fitted on. So
:func:`learn_plant_normal` diagnoses every history day the calibration was made from, each
against the plant's normal learned from the *other* days (the history's ``[model_error]``
refitted without it at the deployed parameters), and keeps per day

* every candidate's log-evidence against ``none`` (:func:`evidence_against_none`);
* the day's errors with the inlet moisture read from the temperatures (what the sensor
  does, :func:`day_errors`) and open loop (what ``validate`` reports beside it).

Leaving the day out of the normal, not out of the seven shared parameters, is the cheap
equivalent of a leave-one-day-out calibration: the parameters are fitted across every day's
windows (one day moves them little), while the normal's day levels and wander are what make
a day look usual, and a normal that saw the day judges it too kindly. That the two agree is
not measured here (a calibration per left-out day costs minutes each); the difference it
makes is to the parameters only.

:class:`PlantNormal` is stored beside the calibration as ``PARAMS.plant-normal.json``
(:func:`normal_path`, :meth:`PlantNormal.write`), with the digest of the PARAMS.toml it was
learned for: a normal learned for other parameters is not used (:func:`read_plant_normal`).
``softsensor learn-normal`` writes it; :func:`learn_plant_normal` is the one function the
calibration path calls to do the same.

How the probabilities use it (:meth:`PlantNormal.log_bayes_bound`): on this plant's healthy
history days a candidate's evidence ``e`` has a median ``m`` and a robust spread ``s`` (1.4826
times the median absolute deviation, at least :data:`MIN_SD`: a history day with an event in
it moves neither), so a new day's evidence has a tail probability ``p`` under health, from
the normal tail of ``(e - m) / s``. The largest Bayes factor a tail probability ``p`` can
carry is ``1 / (-e p ln p)`` for ``p < 1/e``, and 1 above (Sellke, Bayarri and Berger, "Calibration
of p values for testing precise null hypotheses", The American Statistician 55, 2001), and
the candidate's Bayes factor against ``none`` is the smaller of that and the model's own
``exp(e)`` less what a typical healthy day of this plant reaches (``exp(e - m)`` where ``m``
is positive: far out, where the tail bound no longer binds, the evidence counts only beyond
the plant's usual level). A healthy day two spreads out then carries a factor of at most
4, three spreads out 41, four 1200: with the prior's one day in ten shared by seven causes,
a cause reaches a probability of one half only beyond three spreads.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import norm

from softsensor.calibration.dataset import Segment, segment_from_day
from softsensor.calibration.model_error_fit import fit_model_error
from softsensor.calibration.open_loop_errors import open_loop_fit, prepared
from softsensor.errors import ConfigError, SoftsensorError
from softsensor.estimation.model_error import model_error_of
from softsensor.model import DryerModel
from softsensor.plantconfig import PlantConfig, with_table
from softsensor.signals import OUTPUT_NAMES

#: The file beside PARAMS.toml that holds its plant normal: ``params.toml`` ->
#: ``params.plant-normal.json``.
NORMAL_SUFFIX = ".plant-normal.json"
#: Least spread of a candidate's evidence over the healthy history days [nats]: a candidate
#: whose evidence was the same on every history day (a cause the residuals ruled out before
#: any fit) still has a day-to-day spread the history was too short to show.
MIN_SD = 1.0
#: A normal distribution's standard deviation per median absolute deviation.
MAD_TO_SD = 1.4826
#: Evidence below this is read as this [nats] when the spread is estimated: a cause a day
#: cannot show (``-inf``) or rules out says nothing about how far a healthy day reaches.
EVIDENCE_FLOOR = -30.0
#: The two ways a day's errors are measured (:func:`day_errors`).
MODES = ("sensor", "open_loop")


@dataclass(frozen=True)
class HistoryDay:
    """One history day as judged against a normal that did not see it.

    ``evidence``: every candidate's log-evidence against ``none`` [nats]; ``named``: what the
    diagnosis named on the day's evidence alone; ``errors``: per mode of :data:`MODES`, the
    RMSE per channel of ``OUTPUT_NAMES`` [K, K, kg/kg]."""

    source: str
    hours: float
    evidence: dict[str, float]
    named: str
    errors: dict[str, dict[str, float]]

    def to_json(self) -> dict[str, Any]:
        return {"source": self.source, "hours": round(self.hours, 3),
                "evidence": {k: _finite(v) for k, v in self.evidence.items()},
                "named": self.named,
                "errors": {m: {k: _finite(v) for k, v in e.items()}
                           for m, e in self.errors.items()}}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> HistoryDay:
        return cls(str(doc["source"]), float(doc.get("hours", 0.0)),
                   {k: -math.inf if v is None else float(v)
                    for k, v in dict(doc["evidence"]).items()},
                   str(doc.get("named", "")),
                   {m: {k: math.nan if v is None else float(v) for k, v in dict(e).items()}
                    for m, e in dict(doc.get("errors", {})).items()})


def _finite(x: float) -> float | None:
    return round(float(x), 4) if math.isfinite(x) else None


@dataclass(frozen=True)
class PlantNormal:
    """The history days' verdicts (module docstring) and the PARAMS.toml they belong to."""

    days: tuple[HistoryDay, ...]
    params_digest: str
    method: str
    seconds: float = 0.0

    @property
    def n_days(self) -> int:
        return len(self.days)

    def evidence(self, cause: str) -> np.ndarray:
        """``cause``'s log-evidence against ``none`` on every history day that has it."""
        x = np.array([d.evidence[cause] for d in self.days if cause in d.evidence], float)
        return np.maximum(x, EVIDENCE_FLOOR)

    def spread(self, cause: str) -> tuple[float, float] | None:
        """``(median, robust spread)`` of ``cause``'s evidence on the history days (module
        docstring) [nats]; None when no history day has it."""
        x = self.evidence(cause)
        if x.size == 0:
            return None
        m = float(np.median(x))
        return m, max(MAD_TO_SD * float(np.median(np.abs(x - m))), MIN_SD)

    def log_bayes_bound(self, cause: str, e: float) -> float | None:
        """The largest log Bayes factor against ``none`` that evidence ``e`` of ``cause`` can
        carry on this plant (module docstring), at most ``e`` less the history days' median
        where that is positive; None when no history day has the cause."""
        ms = self.spread(cause)
        if ms is None:
            return None
        if not math.isfinite(e):
            return e
        log_p = float(norm.logsf((e - ms[0]) / ms[1]))
        bound = 0.0 if log_p >= -1.0 else -1.0 - log_p - math.log(-log_p)
        return min(e - max(ms[0], 0.0), bound)

    def errors(self, mode: str, channel: str) -> np.ndarray:
        """Every history day's RMSE of ``channel`` in ``mode`` (:data:`MODES`), the unknown
        ones left out."""
        x = np.array([d.errors.get(mode, {}).get(channel, math.nan) for d in self.days], float)
        return x[np.isfinite(x)]

    def to_json(self) -> dict[str, Any]:
        return {"params_digest": self.params_digest, "method": self.method,
                "seconds": round(self.seconds, 1), "days": [d.to_json() for d in self.days]}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> PlantNormal:
        return cls(tuple(HistoryDay.from_json(d) for d in doc["days"]),
                   str(doc.get("params_digest", "")), str(doc.get("method", "")),
                   float(doc.get("seconds", 0.0)))

    def write(self, params_path: str | Path) -> Path:
        """Write beside ``params_path`` (:func:`normal_path`); the path written."""
        path = normal_path(params_path)
        path.write_text(json.dumps(self.to_json(), indent=1) + "\n", encoding="utf-8")
        return path


#: A day's RMSE in a mode is within the plant's history when it is at most the largest of
#: its history days' or this many robust spreads above their median (the spread at least a
#: tenth of the median: a handful of days that happened to agree).
SPREAD_Z = 3.0


def history_check(normal: PlantNormal | None, mode: str, rmse: Mapping[str, float]
                  ) -> dict[str, dict[str, Any]]:
    """Per channel, ``rmse`` in ``mode`` (:data:`MODES`) against the plant's history days in
    the same mode: ``{"rmse", "history_median", "upper", "days", "verdict"}``, the verdict
    ``within`` (at most ``upper``: the largest history day's, or :data:`SPREAD_Z` robust
    spreads above their median, whichever is larger), ``beyond``, or ``unknown`` (no
    normal, fewer than two history days with the channel, or no value)."""
    out: dict[str, dict[str, Any]] = {}
    for ch in OUTPUT_NAMES:
        r = float(rmse.get(ch, math.nan))
        x = normal.errors(mode, ch) if normal is not None else np.zeros(0)
        if x.size < 2 or not math.isfinite(r):
            out[ch] = {"rmse": _finite(r), "history_median": None, "upper": None,
                       "days": int(x.size), "verdict": "unknown"}
            continue
        med = float(np.median(x))
        sd = max(MAD_TO_SD * float(np.median(np.abs(x - med))), 0.1 * med)
        upper = max(float(np.max(x)), med + SPREAD_Z * sd)
        out[ch] = {"rmse": r, "history_median": med, "upper": upper, "days": int(x.size),
                   "verdict": "within" if r <= upper else "beyond"}
    return out


def history_checks(params_path: str | Path, sensor_rmse: Mapping[str, float],
                   open_loop_rmse: Mapping[str, float]) -> dict[str, Any]:
    """``validate``'s ``history`` object: the plant normal beside ``params_path``
    (:func:`read_plant_normal`; ``note`` says why there is none) and, per mode of
    :data:`MODES`, :func:`history_check` of the day's errors."""
    normal, why_not = read_plant_normal(params_path)
    return {"history_days": 0 if normal is None else normal.n_days, "note": why_not,
            "sensor": history_check(normal, "sensor", sensor_rmse),
            "open_loop": history_check(normal, "open_loop", open_loop_rmse)}


def normal_path(params_path: str | Path) -> Path:
    """Where the plant normal of ``params_path`` is kept (:data:`NORMAL_SUFFIX`)."""
    p = Path(params_path)
    return p.with_name(p.stem + NORMAL_SUFFIX)


def params_digest(params_path: str | Path) -> str:
    """SHA-256 of the PARAMS.toml's bytes (which parameters a normal was learned for)."""
    return hashlib.sha256(Path(params_path).read_bytes()).hexdigest()


def read_plant_normal(params_path: str | Path) -> tuple[PlantNormal | None, str | None]:
    """``(normal, None)`` kept beside ``params_path``, or ``(None, why not)``: none there, or
    one learned for another PARAMS.toml (its digest differs). A file that is not a plant
    normal raises :class:`ConfigError` naming it."""
    path = normal_path(params_path)
    if not path.is_file():
        return None, (f"no plant normal beside {params_path} ({path.name}; `softsensor "
                      f"learn-normal` writes it from the history days)")
    try:
        normal = PlantNormal.from_json(json.loads(path.read_text(encoding="utf-8")))
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a plant normal ({exc})") from exc
    if normal.params_digest != params_digest(params_path):
        return None, (f"{path.name} was learned for other parameters than {params_path}'s: "
                      f"learn it again")
    return normal, None


def evidence_against_none(candidates: Sequence[Any]) -> dict[str, float]:
    """Every candidate cause's log-evidence less ``none``'s (the largest where a cause has
    several entries), from :class:`~.posterior.Candidate` s (``cause``, ``log_evidence``)."""
    L_none = next(c.log_evidence for c in candidates if c.cause == "none")
    out: dict[str, float] = {}
    for c in candidates:
        if c.cause != "none":
            out[c.cause] = max(out.get(c.cause, -math.inf), c.log_evidence - L_none)
    return out


def without_day(config: PlantConfig, model: DryerModel, segments: Sequence[Segment],
                i: int) -> PlantConfig:
    """``config`` with its ``[model_error]`` refitted on every history day but ``i``, at its
    parameters and the history's inlet level (module docstring); ``config`` itself when it
    has no ``[model_error]`` or there is no other day."""
    me = model_error_of(config)
    others = [s for j, s in enumerate(segments) if j != i]
    if me is None or not others:
        return config
    refit = fit_model_error(model, others, config.parameter_vector(), me.moisture_in,
                            me.moisture_in_day_sd, me.latest_moisture_in)
    return with_table(config, "model_error", refit.to_table())


def day_errors(config: PlantConfig, seg: Segment, model: DryerModel) -> dict[str, dict[str, float]]:
    """The day's RMSE per channel with the inlet moisture read from the temperatures (the
    sensor's mode, ``"sensor"``: :func:`~softsensor.calibration.validation.validate_many`
    with the config's calibration objective) and open loop (``"open_loop"``:
    :func:`~softsensor.calibration.open_loop_errors.open_loop_fit`), as ``validate``
    reports them."""
    from softsensor.calibration.calibration_run import objective_spec
    from softsensor.calibration.settings import calibration_settings
    from softsensor.calibration.validation import validate_many

    out: dict[str, dict[str, float]] = {}
    fit = open_loop_fit(config, [seg], model)
    out["open_loop"] = {n: float(fit.rmse[n]) for n in OUTPUT_NAMES}
    try:
        segs = [prepared(config, seg)]
        spec = objective_spec(model, segs, config, calibration_settings(config))
        read = validate_many(segs, config, spec, [config.parameter_vector()], [None], model)[0]
        out["sensor"] = {n: float(read.fit.rmse[n]) for n in OUTPUT_NAMES}
    except SoftsensorError:  # a day without lab results: no sensor-mode lab error
        out["sensor"] = {n: math.nan for n in OUTPUT_NAMES}
    return out


METHOD = ("each history day diagnosed and validated against the plant's normal "
          "([model_error]) refitted on the other days at the deployed parameters")


def learn_plant_normal(config: PlantConfig, days: Sequence[Any], params_path: str | Path,
                       *, sources: Sequence[str] | None = None,
                       progress: Callable[[str], None] | None = None,
                       diagnose_kwargs: Mapping[str, Any] | None = None) -> PlantNormal:
    """The plant normal of the calibration ``config`` (loaded from ``params_path``) from its
    history ``days`` (recorded or simulated days; module docstring). The calibration path
    calls this after writing PARAMS.toml, then :meth:`PlantNormal.write`.
    ``diagnose_kwargs``: passed to :func:`~.diagnose_day.diagnose` (tests narrow it)."""
    from softsensor.diagnosis.diagnose_day import diagnose

    say = progress or (lambda _m: None)
    t0 = time.perf_counter()
    names = list(sources) if sources is not None else [f"history day {i + 1}"
                                                       for i in range(len(days))]
    model = DryerModel(config)
    segs = [segment_from_day(d, config, source=s) for d, s in zip(days, names, strict=True)]
    out = []
    for i, (day, seg) in enumerate(zip(days, segs, strict=True)):
        say(f"history day {i + 1} of {len(days)}: {names[i]}")
        cfg_i = without_day(config, model, segs, i)
        d = diagnose(cfg_i, day, source=names[i], model=model, normal=None,
                     **dict(diagnose_kwargs or {}))
        out.append(HistoryDay(names[i], float(seg.hours), evidence_against_none(d.candidates),
                              d.cause, day_errors(cfg_i, seg, model)))
    return PlantNormal(tuple(out), params_digest(params_path), METHOD,
                       time.perf_counter() - t0)


def replace_days(normal: PlantNormal, days: Sequence[HistoryDay]) -> PlantNormal:
    """``normal`` with other history days (tests: a shorter history)."""
    return dataclasses.replace(normal, days=tuple(days))


__all__ = ["EVIDENCE_FLOOR", "MAD_TO_SD", "MIN_SD", "MODES", "NORMAL_SUFFIX", "SPREAD_Z",
           "HistoryDay", "PlantNormal", "day_errors", "evidence_against_none",
           "history_check", "history_checks", "learn_plant_normal", "normal_path", "params_digest",
           "read_plant_normal", "replace_days", "without_day"]
