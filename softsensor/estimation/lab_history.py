"""Late lab results: validation, duplicates, the tick history they are applied to, and JSON.

A lab result logged at ``log_time_ns`` describes the fibre at ``sample_time_ns``, tens of
minutes earlier. The estimators keep a history of their ticks so that such a result can be
applied at the tick whose window holds its sample time (see :mod:`softsensor.estimation.ukf`).
This module holds what does not depend on the filter:

* :func:`lab_problem`: why a result cannot be true (non-finite or out-of-range value, sample
  taken after the result was logged);
* :class:`LabBook`: the sample ids already seen (a duplicate is ignored) and the results whose
  sample time lies after the last tick (applied when their window arrives);
* :class:`TickRecord`: one tick of the history (window, inputs, filter state at its start,
  lab results applied there, what it produced) and :class:`FilterState`;
* JSON round trips of all of these, :class:`~softsensor.estimation.base.Window` and
  :class:`~softsensor.estimation.base.LabResult` for checkpoints. Floats go through ``repr`` in
  :mod:`json`, so a round trip is exact and a restored estimator continues bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.estimation.consistency import Innovation
from softsensor.estimation.settings import EstimatorSettings
from softsensor.messages import LabResult, Window


def lab_problem(lab: LabResult, settings: EstimatorSettings) -> str | None:
    """Why ``lab`` cannot be a true result (``None`` when it can).

    Checks: ``moisture_out`` finite and within ``[lab_min, lab_max]`` [kg/kg]; a non-empty
    ``sample_id``; the sample time not after the log time.
    """
    v = lab.moisture_out
    if not isinstance(v, (int, float)) or not math.isfinite(v):
        return f"lab {lab.sample_id!r}: moisture_out is not a finite number ({v!r})"
    if not settings.lab_min <= v <= settings.lab_max:
        return (f"lab {lab.sample_id!r}: moisture_out {v:g} kg/kg outside the possible range "
                f"[{settings.lab_min:g}, {settings.lab_max:g}] (estimator.lab_min/lab_max)")
    if not lab.sample_id:
        return "lab result without sample_id"
    if lab.log_time_ns is not None and lab.sample_time_ns > lab.log_time_ns:
        ahead = (lab.sample_time_ns - lab.log_time_ns) / 60e9
        return (f"lab {lab.sample_id!r}: sample_time_ns is {ahead:.1f} min after the result "
                f"was logged")
    return None


@dataclass
class LabBook:
    """Sample ids seen and lab results waiting for their window.

    Attributes
    ----------
    seen : dict[str, int]
        ``sample_id -> sample_time_ns`` of every result accepted or skipped for age, so a
        duplicate is recognised; entries older than the history are pruned.
    pending : list[LabResult]
        Accepted results whose sample time is after the last tick, oldest sample first.
    """

    seen: dict[str, int] = field(default_factory=dict)
    pending: list[LabResult] = field(default_factory=list)

    def is_duplicate(self, lab: LabResult) -> bool:
        """True when ``lab.sample_id`` was seen before."""
        return lab.sample_id in self.seen

    def remember(self, lab: LabResult) -> None:
        """Record ``lab.sample_id`` as seen."""
        self.seen[lab.sample_id] = int(lab.sample_time_ns)

    def add_pending(self, lab: LabResult) -> None:
        """Queue ``lab`` until the window holding its sample time is ticked."""
        self.pending.append(lab)
        self.pending.sort(key=lambda r: (r.sample_time_ns, r.sample_id))

    def take_due(self, end_ns: int) -> list[LabResult]:
        """Remove and return the pending results with ``sample_time_ns <= end_ns``."""
        due = [r for r in self.pending if r.sample_time_ns <= end_ns]
        self.pending = [r for r in self.pending if r.sample_time_ns > end_ns]
        return due

    def prune(self, before_ns: int) -> None:
        """Forget seen ids with sample times before ``before_ns`` (older than the history).

        A repeat of a forgotten id is refused anyway: its sample time lies before the history.
        """
        self.seen = {k: t for k, t in self.seen.items() if t >= before_ns}

    def to_json(self) -> dict[str, Any]:
        return {"seen": dict(self.seen), "pending": [lab_to_json(r) for r in self.pending]}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> LabBook:
        return cls(seen={str(k): int(t) for k, t in data["seen"].items()},
                   pending=[lab_from_json(r) for r in data["pending"]])


def lab_to_json(lab: LabResult) -> dict[str, Any]:
    """JSON form of a lab result."""
    return {"sample_time_ns": int(lab.sample_time_ns), "moisture_out": float(lab.moisture_out),
            "sample_id": lab.sample_id,
            "log_time_ns": None if lab.log_time_ns is None else int(lab.log_time_ns)}


def lab_from_json(data: dict[str, Any]) -> LabResult:
    """Inverse of :func:`lab_to_json`."""
    lt = data.get("log_time_ns")
    return LabResult(sample_time_ns=int(data["sample_time_ns"]),
                     moisture_out=float(data["moisture_out"]), sample_id=str(data["sample_id"]),
                     log_time_ns=None if lt is None else int(lt))


def window_to_json(w: Window) -> dict[str, Any]:
    """JSON form of a window (missing means as ``null``)."""
    return {"start_ns": int(w.start_ns), "end_ns": int(w.end_ns),
            "means": {k: (None if v is None or not math.isfinite(v) else float(v))
                      for k, v in w.means.items()},
            "n_scans": int(w.n_scans), "n_good": {k: int(v) for k, v in w.n_good.items()},
            "stale": bool(w.stale), "reasons": dict(w.reasons), "bin_s": float(w.bin_s),
            "bins": {k: [None if v is None or not math.isfinite(v) else float(v) for v in vs]
                     for k, vs in w.bins.items()},
            "refused": {k: int(v) for k, v in w.refused.items()}}


def window_from_json(data: dict[str, Any]) -> Window:
    """Inverse of :func:`window_to_json`."""
    return Window(start_ns=int(data["start_ns"]), end_ns=int(data["end_ns"]),
                  means={k: (None if v is None else float(v)) for k, v in data["means"].items()},
                  n_scans=int(data["n_scans"]),
                  n_good={k: int(v) for k, v in data["n_good"].items()},
                  stale=bool(data["stale"]), reasons={k: str(v) for k, v in
                                                      data["reasons"].items()},
                  bin_s=float(data.get("bin_s", 0.0)),
                  bins={k: [None if v is None else float(v) for v in vs]
                        for k, vs in data.get("bins", {}).items()},
                  refused={k: int(v) for k, v in data.get("refused", {}).items()})


@dataclass(frozen=True)
class FilterState:
    """Mean ``x`` and covariance ``P`` of the filter state, the mean wall state, and the
    filter's adaptive-noise memory (JSON, see :class:`~softsensor.estimation.discrepancy.
    AdaptiveNoise`). Frozen: a tick makes a new one (:func:`~softsensor.estimation.
    ukf_step.step`)."""

    x: np.ndarray
    P: np.ndarray
    wall: np.ndarray | None
    adapt: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"x": self.x.tolist(), "P": self.P.tolist(),
                "wall": None if self.wall is None else self.wall.tolist(),
                "adapt": dict(self.adapt)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FilterState:
        return cls(np.array(d["x"], float), np.array(d["P"], float),
                   None if d["wall"] is None else np.array(d["wall"], float),
                   dict(d.get("adapt", {})))


@dataclass
class TickRecord:
    """One tick of the history: what is needed to re-run it, and what it produced."""

    window: Window
    u: np.ndarray
    held: list[str]
    start: FilterState
    labs: list[LabResult] = field(default_factory=list)
    body: dict[str, Any] = field(default_factory=dict)
    innovation: Innovation = field(default_factory=Innovation)

    def to_json(self) -> dict[str, Any]:
        inn = self.innovation
        return {"window": window_to_json(self.window), "u": self.u.tolist(),
                "held": list(self.held), "start": self.start.to_json(),
                "labs": [lab_to_json(r) for r in self.labs], "body": self.body,
                "innovation": {"nis": inn.nis, "dof": inn.dof, "normalised": inn.normalised}}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TickRecord:
        inn = d["innovation"]
        return cls(window_from_json(d["window"]), np.array(d["u"], float), list(d["held"]),
                   FilterState.from_json(d["start"]), [lab_from_json(r) for r in d["labs"]],
                   dict(d["body"]), Innovation(float(inn["nis"]), int(inn["dof"]),
                                               dict(inn["normalised"])))
