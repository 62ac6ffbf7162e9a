"""Structural alternatives of the model, chosen by evidence from history (issue 29).

Seven multipliers scale rates; they cannot change a shape, such as how steeply the outlet
moisture answers the inlet air temperature near the end of drying. Where the multipliers'
front (:mod:`.trade_off`) holds no point that fits both the temperatures and the labs, the
structure is what differs from the dryer's. Each :class:`~softsensor.model.structure.Alternative`
is a set of keys of the plant sections (``fiber.bound_fraction``, ``cyclone.hold_up_time``, ...)
with its source: a named change of the model's physics that the config already parameterises.

The search (:func:`search`) runs after the paper's form has been calibrated on the history
windows. For every alternative, the model is built with its keys, the multipliers start
where the paper's form ended (its prior centred there) and the local polish
(:mod:`.refine`) re-fits them on the same windows; the result is scored on the
same held-out hours (inlet moisture read from the temperatures, labs out of sample) by the
profile likelihood ``sum_m (N_m / 2) ln MSE_m``, each channel by its own scale. An
alternative's evidence is the baseline's score less its own, less ``(k / 2) ln N`` for its
``k`` structural constants (a Bayesian information criterion over the ``N`` held-out
samples). One is adopted only when that gain is positive and its held-out point (the worse
temperature, the labs) is not beaten on both by any point of the paper's front: it moves the
front, not only the balance between the channels. The adopted keys and the table of evidence
go into PARAMS.toml's ``[structure]`` (:func:`softsensor.plantconfig.load_parameters`
applies them), so ``validate``, ``replay``, ``run`` and ``diagnose`` use the structure from
then on.

What it costs: every alternative is first screened with a polish whose Jacobian is
differenced once at its start and then carried by Broyden's update
(:class:`~.refine.BroydenResiduals`: a step costs one simulation, not one per parameter
more), the alternatives side by side, one per core. The one the screen would adopt is then
polished again as the paper's form is (the Jacobian differenced at every step), and the
decision is taken again on that; so what is adopted and deployed is what the differenced
polish gives, and a rejected alternative's row says how it was polished (``polish``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.calibration.calibration_run import objective_spec, search_model
from softsensor.calibration.dataset import Segment
from softsensor.calibration.objective import RMSE_FLOOR, Evaluation
from softsensor.calibration.refine import refine
from softsensor.calibration.settings import CalibrationSettings
from softsensor.calibration.trade_off import TEMPERATURES, TradeOff
from softsensor.calibration.validation import validate_many
from softsensor.errors import SoftsensorError
from softsensor.model import DryerModel
from softsensor.model.dryer import default_threads
from softsensor.model.structure import Alternative as ModelAlternative
from softsensor.model.structure import commission, structure_space
from softsensor.plantconfig import PlantConfig
from softsensor.signals import OUTPUT_NAMES

#: Polish of each alternative (passes, evaluations per pass): it starts at the paper's form's
#: optimum, so the multipliers move less than from a TPE trial.
ALTERNATIVE_POLISH = (2, 8)


@dataclass(frozen=True)
class Candidate:
    """A structural alternative to try: one of the model's library
    (:func:`softsensor.model.structure.structure_space`) with values for its free keys.
    ``k`` counts the structural constants it fixes (the penalty's count)."""

    name: str
    alternative: ModelAlternative
    values: Mapping[str, float]
    k: int
    what: str

    @property
    def source(self) -> str:
        return self.alternative.source

    def config(self, start: PlantConfig) -> PlantConfig:
        """``start`` (the paper's form at its calibrated multipliers) with this alternative:
        a drying law commissioned to ``start``'s nominal outlet moisture (its rate
        multipliers scaled together), the other multipliers as ``start`` has them."""
        return commission(start, self.alternative, self.values)

    def keys(self, deployed: PlantConfig) -> dict[str, Any]:
        """The plant keys that make ``deployed`` this alternative (PARAMS.toml's
        ``[structure]``): the fixed and free keys, and the Table 1 bounds it widens."""
        out: dict[str, Any] = {**self.alternative.sets, **self.values}
        for name in self.alternative.parameters:
            spec = deployed.parameters[name]
            out[f"parameters.{name}.low"] = float(spec.low)
            out[f"parameters.{name}.high"] = float(spec.high)
        return out


def _find(name: str) -> ModelAlternative:
    return next(a for a in structure_space() if a.name == name)


def default_library(config: PlantConfig) -> list[Candidate]:
    """The alternatives searched by default: the two other drying laws at two shapes each,
    the paper's bound-water rate a factor 3 either way, a longer cyclone hold-up and a
    heat loss that grows in the cold (each from the model's library, around ``config``)."""
    f, c = config.fiber, config.cyclone
    law, paper = _find("drying_law.cdc"), _find("drying_law.double_sigmoid")
    rea, hold, loss = (_find("drying_law.rea"), _find("cyclone.hold_up"),
                       _find("heat_loss.ambient"))
    return [
        Candidate("characteristic drying curve, n = 1", law, {"fiber.cdc_exponent": 1.0}, 2,
                  "Keey's curve: the rate falls linearly to the equilibrium moisture"),
        Candidate("characteristic drying curve, n = 2", law, {"fiber.cdc_exponent": 2.0}, 2,
                  "Keey's curve, falling as the square: a steeper end of drying"),
        Candidate("reaction engineering, b = 5", rea, {"fiber.rea_b": 5.0}, 2,
                  "Chen's REA: the surface vapour falls with the activation energy"),
        Candidate("reaction engineering, b = 20", rea, {"fiber.rea_b": 20.0}, 2,
                  "Chen's REA, its activation energy rising sooner"),
        Candidate("bound-water rate x0.3", paper,
                  {"fiber.bound_fraction": f.bound_fraction * 0.3}, 1,
                  "the paper's law, slower below the critical moisture"),
        Candidate("bound-water rate x3", paper,
                  {"fiber.bound_fraction": min(f.bound_fraction * 3.0, 2e-2)}, 1,
                  "the paper's law, faster below the critical moisture"),
        Candidate("cyclone hold-up x3", hold,
                  {"cyclone.hold_up_time": min(c.hold_up_time * 3.0, 30.0)}, 1,
                  "fibre held longer in the cyclones: more of the drying there"),
        Candidate("heat loss growing in the cold", loss,
                  {"environment.ambient_loss_slope": 0.05}, 1,
                  "outside heat loss 5 % larger per kelvin of ambient below 283 K"),
    ]


def held_out_score(ev: Evaluation) -> tuple[float, int]:
    """Profile negative log-likelihood ``sum_m (N_m / 2) ln MSE_m`` of a validation and its
    sample count (module docstring)."""
    total, n_all = 0.0, 0
    for c, name in enumerate(OUTPUT_NAMES):
        n = int(ev.fit.n[name])
        r = float(ev.fit.rmse[name])
        if n and math.isfinite(r):
            total += 0.5 * n * math.log(max(r, RMSE_FLOOR[c]) ** 2)
            n_all += n
    return (total if n_all else math.inf), n_all


@dataclass(frozen=True)
class Scored:
    """One alternative calibrated and scored (module docstring)."""

    candidate: Candidate
    keys: dict[str, Any]
    theta: np.ndarray
    held_out: dict[str, float]
    open_loop: dict[str, float]
    score: float
    gain: float
    adopted: bool = False
    why_not: str = ""
    #: how its polish took the Jacobian: "broyden" (screened) or "differences" (the
    #: alternative the search adopts or would adopt, polished as the paper's form is)
    polish: str = "broyden"

    def point(self) -> tuple[float, float]:
        return (max(self.held_out[c] for c in TEMPERATURES), self.held_out["moisture_out"])

    def row(self) -> dict[str, Any]:
        a = self.candidate
        return {"name": a.name, "keys": self.keys, "k": a.k, "what": a.what,
                "source": a.source, "params": list(map(float, self.theta)),
                "held_out_rmse": self.held_out, "open_loop_rmse": self.open_loop,
                "score": self.score, "gain": self.gain, "adopted": self.adopted,
                "why_not": self.why_not, "polish": self.polish}


@dataclass(frozen=True)
class StructureSearch:
    """The baseline's held-out score and every candidate; ``adopted`` the chosen one."""

    baseline_score: float
    baseline_held_out: dict[str, float]
    candidates: list[Scored]
    #: the estimator's prequential lab score of the baseline and of the alternative the
    #: held-out evidence chose (:mod:`.sensor_score`), when it was asked
    sensor: dict[str, Any] | None = None

    def overruled(self, why: str, sensor: dict[str, Any]) -> StructureSearch:
        """This search with its adopted alternative set aside by the sensor's score."""
        cands = [dataclasses.replace(c, adopted=False, why_not=why) if c.adopted else c
                 for c in self.candidates]
        return dataclasses.replace(self, candidates=cands, sensor=sensor)

    @property
    def adopted(self) -> Scored | None:
        return next((c for c in self.candidates if c.adopted), None)

    def line(self) -> str:
        """One line for a person."""
        a = self.adopted
        if a is None:
            best = max(self.candidates, key=lambda c: c.gain, default=None)
            tail = "" if best is None else f" (best: {best.candidate.name}, {best.why_not})"
            if self.sensor:  # the held-out evidence chose one; the estimator's score did not
                return f"structure: the paper's form kept, the estimator's lab score{tail}"
            return (f"structure: the paper's form kept; none of {len(self.candidates)} "
                    f"alternatives earned its place on the held-out data{tail}")
        t, m = a.point()
        return (f"structure: adopted '{a.candidate.name}' ({a.candidate.what}): held-out "
                f"evidence gain {a.gain:.1f}, worse temperature {t:.2f} K, labs {m:.4f} kg/kg")

    def as_dict(self) -> dict[str, Any]:
        return {"baseline_score": self.baseline_score,
                "baseline_held_out_rmse": self.baseline_held_out,
                "adopted": None if self.adopted is None else self.adopted.candidate.name,
                "candidates": [c.row() for c in self.candidates], "sensor": self.sensor}

    def params_table(self) -> dict[str, Any] | None:
        """PARAMS.toml's ``[structure]``: the adopted keys as nested tables and the evidence
        (None when the paper's form was kept)."""
        a = self.adopted
        if a is None:
            return None
        out: dict[str, Any] = {}
        for dotted, v in a.keys.items():
            node = out
            *path, key = dotted.split(".")
            for part in path:
                node = node.setdefault(part, {})
            node[key] = v
        out["evidence"] = {"adopted": a.candidate.name, "source": a.candidate.source,
                           "gain": a.gain, "baseline_score": self.baseline_score,
                           **({"sensor": self.sensor} if self.sensor else {}),
                           "candidates": [{k: v for k, v in c.row().items()
                                           if k in ("name", "gain", "adopted", "why_not",
                                                    "held_out_rmse")}
                                          for c in self.candidates]}
        return out


def _dominated(point: tuple[float, float], front: TradeOff | None) -> bool:
    """True when a held-out point of the paper's ``front`` is at least as good on both."""
    if front is None:
        return False
    t, m = point
    return any(p.held_out is not None and p.worst_temperature() <= t
               and float(p.held_out["moisture_out"]) <= m for p in front.points)


def search(fit: Sequence[Segment], held: Sequence[Segment], config: PlantConfig,
           calibration: CalibrationSettings, baseline_theta: np.ndarray,
           baseline: Evaluation, front: TradeOff | None,
           library: Sequence[Candidate], *,
           say: Callable[[str], None] | None = None) -> StructureSearch:
    """Calibrate and score every alternative of ``library`` (module docstring) on the
    baseline's fitted segments ``fit`` and its held-out ``held`` pieces, against the paper's form at
    ``baseline_theta`` (its validation ``baseline``, its ``front``). The baseline must be
    polished (:func:`~.history_calibration.calibrate_history` searches only then)."""
    say = say or (lambda s: None)
    # the multipliers start at the baseline's optimum and move little: a shorter polish
    light = dataclasses.replace(calibration, polish_passes=min(calibration.polish_passes,
                                                               ALTERNATIVE_POLISH[0]),
                                polish_evaluations=min(calibration.polish_evaluations,
                                                       ALTERNATIVE_POLISH[1]))
    base_score, n = held_out_score(baseline)
    penalty_per_k = 0.5 * math.log(max(n, 2))
    start = config.with_parameters(baseline_theta)
    tried = []
    for alt in library:
        try:
            tried.append((alt, alt.config(start)))
        except SoftsensorError as exc:  # no commissioning within the bounds: not a candidate
            say(f"structure: {alt.name} skipped: {exc}")
    workers = min(default_threads(), len(tried))

    def scored(alt: Candidate, cfg: PlantConfig, broyden: bool,
               threads: int | None = None) -> Scored:
        ev, theta = _calibrated(fit, held, cfg, light, threads=threads, broyden=broyden)
        score, _ = held_out_score(ev)
        return Scored(alt, alt.keys(cfg), theta, {k: float(v) for k, v in ev.fit.rmse.items()},
                      {k: float(v) for k, v in ev.open_fit.rmse.items()}, score,
                      base_score - score - alt.k * penalty_per_k,
                      polish="broyden" if broyden else "differences")

    def screened(item: tuple[Candidate, PlantConfig]) -> Scored:
        say(f"structure: {item[0].name}")
        # with several workers each runs its members in its own thread: every core busy with
        # a whole alternative, none waiting on another's short calls
        return scored(*item, broyden=True, threads=1 if workers > 1 else None)

    with ThreadPoolExecutor(max_workers=max(workers, 1),
                            thread_name_prefix="structure") as pool:
        out = list(pool.map(screened, tried))
    # the screen's choice polished again as the paper's form is (the Jacobian differenced at
    # every step), so that what is adopted and deployed is what that polish gives; should it
    # then lose its place, the next choice likewise
    decided = _decided(out, front, penalty_per_k)
    while (pick := next((i for i, c in enumerate(decided) if c.adopted), None)) is not None \
            and out[pick].polish == "broyden":
        say(f"structure: {out[pick].candidate.name}, the polish differenced")
        out[pick] = scored(*tried[pick], broyden=False)  # alone: its members on every core
        decided = _decided(out, front, penalty_per_k)
    return StructureSearch(base_score, {k: float(v) for k, v in baseline.fit.rmse.items()},
                           decided)


def _calibrated(fit: Sequence[Segment], held: Sequence[Segment], cfg: PlantConfig,
                calibration: CalibrationSettings, threads: int | None = None,
                broyden: bool = True) -> tuple[Evaluation, np.ndarray]:
    """An alternative's config ``cfg`` calibrated from its commissioned start on ``fit``
    (the polish, with Broyden's Jacobian unless not ``broyden``) and validated on ``held``:
    the validation and the parameters.

    What :func:`~.calibration_run.calibrate` with one trial and the polish gives, less the
    work whose results the search does not read: the one trial (the study's first trial is
    the config's values, enqueued, so it is the polish's start whatever it scores), the
    re-evaluation of the result and of the start on the fitted windows, and the validation
    of the start and of the study's front on the held-out hours (each as many simulations of
    the held-out hours as the result's own). ``threads``: the model's
    (:class:`~softsensor.model.dryer.DryerModel`); every member gets the numbers it gets
    alone, so the result does not depend on them."""
    model = DryerModel(cfg, threads=threads)
    fast = search_model(model, calibration)
    spec = objective_spec(model, fit, cfg, calibration)
    start = cfg.parameter_vector()
    polished = refine(model, fit, start, cfg.bounds(), spec, jac_model=fast,
                      passes=calibration.polish_passes, max_nfev=calibration.polish_evaluations,
                      broyden=broyden)
    theta = polished.theta if polished.improved else start
    return validate_many(held, cfg, spec, [theta], [None], model)[0].evaluation, theta


def _decided(out: Sequence[Scored], front: TradeOff | None, penalty_per_k: float
             ) -> list[Scored]:
    """``out`` with the adopted alternative marked (the largest gain above zero that no
    point of the paper's ``front`` dominates) and why each other one was not."""
    adopted = None
    for c in sorted(out, key=lambda c: -c.gain):
        if c.gain > 0 and not _dominated(c.point(), front):
            adopted = c
            break
    final = []
    for c in out:
        if c is adopted:
            final.append(dataclasses.replace(c, adopted=True))
        elif not c.gain > 0:
            final.append(dataclasses.replace(
                c, why_not=f"evidence gain {c.gain:.1f} <= 0 after the penalty "
                           f"{c.candidate.k * penalty_per_k:.1f}"))
        elif _dominated(c.point(), front):
            final.append(dataclasses.replace(
                c, why_not="a point of the paper's front fits both channels as well"))
        else:
            final.append(dataclasses.replace(c, why_not="another alternative gained more"))
    return final


__all__ = ["ALTERNATIVE_POLISH", "Candidate", "Scored", "StructureSearch", "default_library",
           "held_out_score", "search"]
