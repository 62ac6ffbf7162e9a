"""Late lab results: validation, duplicates, the tick history they are applied to, and JSON.

A lab result logged at ``log_time_ns`` describes the fibre at ``sample_time_ns``, tens of
minutes earlier. The estimators keep a history of their ticks so that such a result can be
applied at the tick whose window holds its sample time (see :mod:`softsensor.estimation.ukf`).
This module holds what does not depend on the filter:

* :class:`LabBook`: the sample ids already seen (a duplicate is ignored) and the results
  handed over for the coming tick (sampled after the last one). A result is valid by
  construction (:class:`~softsensor.messages.LabResult` holds the lab-result contract), and
  results wait for their window in one queue, the estimator service's (by
  :attr:`~softsensor.messages.LabResult.due_ns`), not here;
* :class:`TickRecord`: one tick of the history (window, inputs, filter state at its start,
  lab results applied there, what it produced) and :class:`FilterState` (with the peers'
  weights and the band's scale, so that a late result re-weighs them too);
* JSON round trips of all of these, :class:`~softsensor.messages.Window` and
  :class:`~softsensor.messages.LabResult` for checkpoints. Floats go through ``repr`` in
  :mod:`json`, so a round trip is exact and a restored estimator continues bit for bit.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from softsensor.errors import IngestError
from softsensor.estimate import Estimate
from softsensor.estimation.consistency import Innovation
from softsensor.jsonable import finite_or_none
from softsensor.messages import LabResult, Window

log = logging.getLogger(__name__)


@dataclass
class LabBook:
    """Sample ids seen and lab results handed over for the coming tick.

    Attributes
    ----------
    seen : dict[str, int]
        ``sample_id -> sample_time_ns`` of every result accepted or skipped for age, so a
        duplicate is recognised; entries older than the history are pruned.
    pending : list[LabResult]
        Accepted results sampled after the last tick, oldest sample first: the coming tick
        applies them (:meth:`take_due`). They do not wait longer: a result is handed over once
        it is due (:attr:`~softsensor.messages.LabResult.due_ns`), when its window is ticking.
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
        """Hold ``lab`` (sampled after the last tick) for the coming tick."""
        self.pending.append(lab)
        self.pending.sort(key=lambda r: (r.sample_time_ns, r.sample_id))

    def take_due(self, end_ns: int) -> list[LabResult]:
        """Remove every held result and return those sampled by ``end_ns``, the end of the
        window being ticked; one sampled later was handed over before it was due and is
        skipped with a warning (waiting is the service's queue's job, not the estimator's)."""
        due = [r for r in self.pending if r.sample_time_ns <= end_ns]
        for r in self.pending:
            if r.sample_time_ns > end_ns:
                log.warning("lab %r: sampled after the window ending %d ns it was handed over "
                            "for (hand a result over once due: LabResult.due_ns); skipped",
                            r.sample_id, end_ns)
        self.pending = []
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
    """Inverse of :func:`lab_to_json`; ValueError for a result that breaks the lab-result
    contract (a checkpoint is read like any other input)."""
    lt = data.get("log_time_ns")
    try:
        return LabResult(sample_time_ns=int(data["sample_time_ns"]),
                         moisture_out=float(data["moisture_out"]),
                         sample_id=str(data["sample_id"]),
                         log_time_ns=None if lt is None else int(lt))
    except IngestError as exc:
        raise ValueError(str(exc)) from exc


def window_to_json(w: Window) -> dict[str, Any]:
    """JSON form of a window (missing means as ``null``)."""
    return {"start_ns": int(w.start_ns), "end_ns": int(w.end_ns),
            "means": {k: (None if v is None else finite_or_none(v))
                      for k, v in w.means.items()},
            "n_scans": int(w.n_scans), "n_good": {k: int(v) for k, v in w.n_good.items()},
            "stale": bool(w.stale), "reasons": dict(w.reasons), "bin_s": float(w.bin_s),
            "bins": {k: [None if v is None else finite_or_none(v) for v in vs]
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
    filter's adaptive-noise memory (JSON, see :class:`~softsensor.estimation.state_space.
    AdaptiveNoise`). Frozen: a tick makes a new one (:func:`~softsensor.estimation.
    ukf_step.step`)."""

    x: np.ndarray
    P: np.ndarray
    wall: np.ndarray | None
    adapt: dict[str, Any] = field(default_factory=dict)
    #: the peers' weights and the band's scale (:mod:`~softsensor.estimation.peer_blend`);
    #: empty before the first tick and in checkpoints written before them
    peers: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"x": self.x.tolist(), "P": self.P.tolist(),
                "wall": None if self.wall is None else self.wall.tolist(),
                "adapt": dict(self.adapt), "peers": dict(self.peers)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FilterState:
        return cls(np.array(d["x"], float), np.array(d["P"], float),
                   None if d["wall"] is None else np.array(d["wall"], float),
                   dict(d.get("adapt", {})), dict(d.get("peers", {})))


@dataclass(frozen=True)
class TickRecord:
    """One tick of the history: what is needed to run it again, and what it produced (the
    estimate, None until it ran, and the innovation). Frozen: attaching a lab result or
    filtering the tick again makes a new record (:meth:`with_labs`, :meth:`ran`)."""

    window: Window
    u: np.ndarray
    held: tuple[str, ...]
    start: FilterState
    labs: tuple[LabResult, ...] = ()
    estimate: Estimate | None = None
    innovation: Innovation = field(default_factory=Innovation)

    def with_labs(self, labs: tuple[LabResult, ...]) -> TickRecord:
        """This tick with the lab results ``labs`` instead of its own."""
        return replace(self, labs=tuple(labs))

    def ran(self, estimate: Estimate, innovation: Innovation) -> TickRecord:
        """This tick with what filtering it from its ``start`` produced."""
        return replace(self, estimate=estimate, innovation=innovation)

    def to_json(self) -> dict[str, Any]:
        inn = self.innovation
        return {"window": window_to_json(self.window), "u": self.u.tolist(),
                "held": list(self.held), "start": self.start.to_json(),
                "labs": [lab_to_json(r) for r in self.labs],
                "body": {} if self.estimate is None else self.estimate.to_body(),
                "innovation": {"nis": inn.nis, "dof": inn.dof, "normalised": inn.normalised}}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TickRecord:
        inn = d["innovation"]
        body = d["body"]
        return cls(window_from_json(d["window"]), np.array(d["u"], float), tuple(d["held"]),
                   FilterState.from_json(d["start"]), tuple(lab_from_json(r) for r in d["labs"]),
                   Estimate.from_body(body) if body else None,
                   Innovation(float(inn["nis"]), int(inn["dof"]), dict(inn["normalised"])))


__all__ = ["FilterState", "LabBook", "TickRecord", "lab_from_json", "lab_to_json",
           "window_from_json", "window_to_json"]
