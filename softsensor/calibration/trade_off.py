"""The trade-off between the outlet temperatures and the outlet moisture that the seven
multipliers can reach, and whether the model can fit both.

A calibration's cost weighs the channels against each other (eq. 4: 1 K counts as 0.0006
kg/kg of moisture); where the model's structure differs from the dryer's, moving along the
multipliers buys one channel with the other, and one number hides which. Every trial of the
study already scored every channel on the calibration windows (trial attributes
``rmse_<channel>``), so the front costs no extra search: the trials that no other trial beats
on both the worse of the two temperature RMSEs and the lab RMSE. A few of them, spread along
the front, are scored on the held-out data beside the deployed and the current parameters, in
the same batched validation run (:func:`~.validation.validate_many`), in both of its modes:
the inlet moisture read from the temperatures (the lab results out of sample, what the
sensor does) and open loop.

The verdict asks whether any point of that held-out front holds both temperatures within
``temperature_target`` and the lab moisture within ``moisture_target``
(``[calibration]``, 1.0 K and 0.006 kg/kg by default). Where none does, the line says both
things that can be wrong: the front is only what the study's trials reached, so a short study
on a model whose structure is exactly right (the matched plant, 3 trials) misses the targets
too; only a study long enough to converge lets the front speak for the structure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import optuna

from softsensor.calibration.optimize import theta_of

#: Front points (besides the deployed and current ones) scored on the held-out data.
MAX_FRONT_POINTS = 6
#: Temperature channels, whose worse RMSE is the front's first axis.
TEMPERATURES = ("T_dryer_out", "T_cyclone_out")


@dataclass(frozen=True)
class FrontPoint:
    """One parameter set on the trade-off.

    ``label``: ``"deployed"``, ``"current"`` or ``"trial N"``; ``fit``: RMSE per channel on
    the calibration windows (the study's view: inlet trajectory fitted to temperatures and
    labs); ``held_out`` and ``open_loop``: on the held-out data, the inlet read from the
    temperatures (labs out of sample) and with the nominal inlet moisture.
    """

    label: str
    theta: np.ndarray
    fit: dict[str, float]
    held_out: dict[str, float] | None = None
    open_loop: dict[str, float] | None = None

    def worst_temperature(self, which: str = "held_out") -> float:
        rmse = getattr(self, which)
        return max(float(rmse[c]) for c in TEMPERATURES) if rmse else math.nan

    def as_dict(self) -> dict[str, object]:
        return {"label": self.label, "params": list(map(float, self.theta)), "fit": self.fit,
                "held_out": self.held_out, "open_loop": self.open_loop}


def pareto_indices(t: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Indices of the points no other point beats on both ``t`` and ``m`` (lower is
    better), in increasing ``t``."""
    order = np.lexsort((m, t))
    keep, best_m = [], math.inf
    for i in order:
        if m[i] < best_m:
            keep.append(i)
            best_m = m[i]
    return np.asarray(keep, int)


def spread(n: int, k: int) -> list[int]:
    """``k`` indices out of ``range(n)`` spread evenly, both ends included."""
    if n <= k:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)})


def study_front(study: optuna.Study, max_points: int = MAX_FRONT_POINTS) -> list[FrontPoint]:
    """The study's non-dominated trials on (worse temperature RMSE, lab RMSE), at most
    ``max_points`` spread along the front from the best temperatures to the best labs."""
    rows = []
    for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)):
        a = t.user_attrs
        rmse = {c: a.get(f"rmse_{c}") for c in (*TEMPERATURES, "moisture_out")}
        if any(not (isinstance(v, float) and math.isfinite(v)) for v in rmse.values()):
            continue
        rows.append((t.number, theta_of(t.params), rmse))
    if not rows:
        return []
    t_axis = np.array([max(r[2][c] for c in TEMPERATURES) for r in rows])
    m_axis = np.array([r[2]["moisture_out"] for r in rows])
    front = pareto_indices(t_axis, m_axis)
    return [FrontPoint(f"trial {rows[i][0]}", rows[i][1], rows[i][2])
            for i in front[spread(len(front), max_points)]]


@dataclass(frozen=True)
class TradeOff:
    """The front scored on the held-out data and its verdict (module docstring)."""

    points: list[FrontPoint]
    temperature_target: float
    moisture_target: float

    def reaching(self) -> list[FrontPoint]:
        """Points holding both temperatures and the labs within the targets, held out."""
        return [p for p in self.points if p.held_out is not None
                and p.worst_temperature() <= self.temperature_target
                and float(p.held_out["moisture_out"]) <= self.moisture_target]

    def closest(self) -> FrontPoint | None:
        """The held-out point nearest to both targets (largest ratio to its target lowest)."""
        scored = [p for p in self.points if p.held_out is not None]
        if not scored:
            return None
        return min(scored, key=lambda p: max(
            p.worst_temperature() / self.temperature_target,
            float(p.held_out["moisture_out"]) / self.moisture_target))

    def verdict(self) -> str:
        """One line: can the model fit both channels on the held-out data?"""
        t, m = self.temperature_target, self.moisture_target
        ok = self.reaching()
        if ok:
            names = ", ".join(p.label for p in ok)
            return (f"the model can hold both outlet temperatures within {t:g} K while the "
                    f"outlet moisture stays within {m:g} kg/kg on the held-out data ({names})")
        best = self.closest()
        tail = ("" if best is None else
                f" (closest: {best.label}, {best.worst_temperature():.2f} K and "
                f"{float(best.held_out['moisture_out']):.4f} kg/kg)")
        return (f"this model cannot hold the outlet temperatures within {t:g} K while the "
                f"outlet moisture stays within {m:g} kg/kg on the held-out data: no point of "
                f"the front this study found does{tail}: either the study did not search far "
                f"enough or the model's structure differs from this dryer's")

    def as_dict(self) -> dict[str, object]:
        return {"temperature_target_K": self.temperature_target,
                "moisture_target": self.moisture_target, "verdict": self.verdict(),
                "reachable": bool(self.reaching()),
                "points": [p.as_dict() for p in self.points]}


def scored(points: Sequence[FrontPoint], evaluations: Sequence[object]) -> list[FrontPoint]:
    """``points`` with their held-out RMSEs from validation ``evaluations`` (one each: an
    :class:`~.objective.Evaluation` whose ``fit`` reads the inlet from the temperatures and
    whose ``open_fit`` is open loop)."""
    out = []
    for p, ev in zip(points, evaluations, strict=True):
        out.append(FrontPoint(p.label, p.theta, p.fit,
                              {k: float(v) for k, v in ev.fit.rmse.items()},
                              {k: float(v) for k, v in ev.open_fit.rmse.items()}))
    return out


__all__ = ["MAX_FRONT_POINTS", "FrontPoint", "TradeOff", "pareto_indices", "scored", "spread",
           "study_front"]
