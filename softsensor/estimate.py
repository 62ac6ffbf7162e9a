"""The published estimate and health: typed, frozen, to and from their bus bodies.

What the soft sensor says every tick is an :class:`Estimate` (``/softsensor/estimate``,
CONTRACT section 2) and a :class:`Health` (``/softsensor/health``). Both are frozen: the
estimator builds its estimate (the filter's in one place,
:mod:`softsensor.estimation.publication`), the service finishes any estimator's with the
window's facts by one pure step (:func:`softsensor.service.estimator_service.finish`) and says
its health; the daemon adds what only it knows (the recorder's state, what the input limits
dropped, a stalled estimator thread) as fields of a new :class:`Health`, never by editing
text. Every sink (the bus, the recording,
the operator outputs) gets these objects; :meth:`Estimate.to_body` and :meth:`Health.to_body`
are the one place their JSON bodies are written, :meth:`~Estimate.from_body` the one place a
body read back (a checkpoint, a recorded day) becomes one again.

Status and detail are not stored: each judgement that bears on them is a :class:`Reason`
(a status and a sentence), the status is the worst of them (:data:`SEVERITY`) and the detail
their sentences in order. A health's parts are the last tick's verdict, the inputs', the lab's
and, from the daemon, a stall; the recorder's state adds to the detail without changing the
status (an estimate is still good while its recording is paused).

No I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Any, ClassVar

from softsensor.jsonable import finite_or_none

#: Health states from best to worst (CONTRACT section 2).
SEVERITY: Mapping[str, int] = MappingProxyType({"ok": 0, "degraded": 1, "stale": 2})


def worst(*statuses: str) -> str:
    """The worst of ``statuses`` (``ok`` for none); an unknown status counts as
    ``degraded`` (a status no operator screen knows must not read as good)."""
    out = "ok"
    for s in statuses:
        s = s if s in SEVERITY else "degraded"
        if SEVERITY[s] > SEVERITY[out]:
            out = s
    return out


@dataclass(frozen=True)
class Reason:
    """One judgement on a tick or on the service: its status and the sentence that says why."""

    status: str
    text: str


def _num(v: Any) -> float | None:
    """A body's number as a finite float, or None (JSON's null; it has no NaN)."""
    return None if v is None else finite_or_none(v)


def _none_for_nan(obj: Any) -> None:
    """Each ``float | None`` field of the frozen dataclass ``obj`` that holds NaN or an
    infinity set to None (JSON has neither): what no estimator could give is None, whoever
    built the object."""
    for f in fields(obj):
        if f.type == "float | None":
            v = getattr(obj, f.name)
            if v is not None and not math.isfinite(v):
                object.__setattr__(obj, f.name, None)


def _frozen_map(m: Mapping[str, Any] | None) -> Mapping[str, Any]:
    return MappingProxyType(dict(m or {}))


@dataclass(frozen=True)
class SourceEstimate:
    """One source of the published outlet moisture and its weight
    (:mod:`softsensor.estimation.peer_blend`). [-, kg/kg, kg/kg]"""

    weight: float
    moisture_out: float | None
    moisture_out_std: float | None

    def __post_init__(self) -> None:
        _none_for_nan(self)

    def to_body(self) -> dict[str, Any]:
        return {"weight": self.weight, "moisture_out": self.moisture_out,
                "moisture_out_std": self.moisture_out_std}


@dataclass(frozen=True)
class Blend:
    """What the published ``moisture_out`` is made of: the physics' own estimate, each source
    with its weight, the band's conformal scale, the lab results outside the band so far of
    those scored, and the source that leads."""

    moisture_out_physics: float | None
    moisture_out_physics_std: float | None
    sources: Mapping[str, SourceEstimate]
    band_scale: float
    band_misses: tuple[int, int]
    source: str

    def __post_init__(self) -> None:
        _none_for_nan(self)

    def to_body(self) -> dict[str, Any]:
        return {"moisture_out_physics": self.moisture_out_physics,
                "moisture_out_physics_std": self.moisture_out_physics_std,
                "sources": {k: s.to_body() for k, s in self.sources.items()},
                "band_scale": self.band_scale, "band_misses": list(self.band_misses),
                "source": self.source}

    @classmethod
    def from_body(cls, b: Mapping[str, Any]) -> Blend | None:
        if "sources" not in b:
            return None
        sources = {str(k): SourceEstimate(float(v["weight"]), _num(v.get("moisture_out")),
                                          _num(v.get("moisture_out_std")))
                   for k, v in (b.get("sources") or {}).items()}
        misses = b.get("band_misses") or (0, 0)
        return cls(_num(b.get("moisture_out_physics")), _num(b.get("moisture_out_physics_std")),
                   MappingProxyType(sources), float(b.get("band_scale", 1.0)),
                   (int(misses[0]), int(misses[1])), str(b.get("source", "physics")))


@dataclass(frozen=True)
class FilterTerms:
    """The filter's view behind a model-based estimate: its error states, the model's own
    temperatures, the innovation test and the guard (:mod:`softsensor.estimation.ukf`).

    Attributes
    ----------
    moisture_out_window_std : float
        The physics' outlet-moisture standard deviation without the short-term jitter. [kg/kg]
    moisture_out_bias, moisture_out_bias_std : float
        The outlet-moisture bias state and its standard deviation. [kg/kg]
    inlet_gain : float
        The inlet-gain state. [-]
    T_air_in_offset : float
        The heat input's offset state. [K]
    T_offset : float
        That offset seen on the outlet temperatures (times the model's gain). [K]
    T_dryer_out_offset, T_cyclone_out_offset : float
        Each outlet thermometer's own offset state. [K]
    T_dryer_out_model_raw, T_cyclone_out_model_raw : float or None
        The model's outlet temperatures without the offsets. [K]
    nis : float or None
        Normalised innovation squared of the tick (None without a measurement). [-]
    nis_dof : int
        Measurements behind it. [-]
    fallback : bool
        The published ``moisture_out`` is the lab-anchored fallback (the model lost the plant).
    labs_applied : tuple of str
        Sample ids of the lab results applied at this tick.
    discrepancy_priors : str
        Where the error states' priors came from.
    """

    moisture_out_window_std: float | None
    moisture_out_bias: float | None
    moisture_out_bias_std: float | None
    inlet_gain: float | None
    T_air_in_offset: float | None
    T_offset: float | None
    T_dryer_out_offset: float | None
    T_cyclone_out_offset: float | None
    T_dryer_out_model_raw: float | None
    T_cyclone_out_model_raw: float | None
    nis: float | None
    nis_dof: int
    fallback: bool
    labs_applied: tuple[str, ...]
    discrepancy_priors: str

    def __post_init__(self) -> None:
        _none_for_nan(self)

    def to_body(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["labs_applied"] = list(self.labs_applied)
        return out

    @classmethod
    def from_body(cls, b: Mapping[str, Any]) -> FilterTerms | None:
        """The filter's terms a body holds (None when it holds none of them)."""
        if not any(f.name in b for f in fields(cls)):
            return None
        kw = {f.name: _num(b.get(f.name)) for f in fields(cls)
              if f.name not in ("nis_dof", "fallback", "labs_applied", "discrepancy_priors")}
        return cls(**kw, nis_dof=int(b.get("nis_dof") or 0), fallback=bool(b.get("fallback")),
                   labs_applied=tuple(str(s) for s in b.get("labs_applied") or ()),
                   discrepancy_priors=str(b.get("discrepancy_priors", "")))


@dataclass(frozen=True)
class WindowFacts:
    """What the window behind an estimate held, added by the service's finishing step:
    the unit, its scans, whether it was stale, the outlet temperatures measured (beside the
    model's, for operators) [K], and the values the plausibility limits refused per signal,
    with why."""

    unit: str
    n_scans: int
    stale: bool
    T_dryer_out_measured: float | None
    T_cyclone_out_measured: float | None
    inputs_refused: Mapping[str, int] = field(default_factory=dict)
    inputs_refused_why: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _none_for_nan(self)

    def to_body(self) -> dict[str, Any]:
        out: dict[str, Any] = {"unit": self.unit, "n_scans": self.n_scans, "stale": self.stale,
                               "T_dryer_out_measured": self.T_dryer_out_measured,
                               "T_cyclone_out_measured": self.T_cyclone_out_measured}
        if self.inputs_refused:
            out["inputs_refused"] = dict(self.inputs_refused)
            out["inputs_refused_why"] = dict(self.inputs_refused_why)
        return out

    @classmethod
    def from_body(cls, b: Mapping[str, Any]) -> WindowFacts | None:
        """The window's facts a body holds (None when it holds none of them)."""
        if not any(f.name in b for f in fields(cls)):
            return None
        return cls(str(b.get("unit", "")), int(b.get("n_scans") or 0), bool(b.get("stale")),
                   _num(b.get("T_dryer_out_measured")), _num(b.get("T_cyclone_out_measured")),
                   _frozen_map({k: int(v) for k, v in (b.get("inputs_refused") or {}).items()}),
                   _frozen_map({k: str(v) for k, v in
                                (b.get("inputs_refused_why") or {}).items()}))


#: The fields every estimate body carries (CONTRACT section 2), in body order.
CONTRACT_FIELDS: tuple[str, ...] = ("moisture_out", "moisture_out_std", "moisture_in",
                                    "moisture_in_std", "T_dryer_out_model",
                                    "T_cyclone_out_model")


@dataclass(frozen=True)
class Estimate:
    """One tick's estimate (module docstring). Moisture dry basis [kg/kg], temperatures [K],
    times [ns since the epoch, UTC]; a value the tick could not give is None.

    Attributes
    ----------
    window_start_ns, window_end_ns : int
        The window the tick stepped over, ``(start, end]``; the estimate's time is its end.
    estimator : str
        Which estimator made it (``ukf``, ``openloop``).
    moisture_out, moisture_out_std : float or None
        The published outlet moisture and the standard deviation of its band. [kg/kg]
    moisture_in, moisture_in_std : float or None
        The inlet moisture and its standard deviation. [kg/kg]
    T_dryer_out_model, T_cyclone_out_model : float or None
        The model's outlet temperatures with the filter's offsets. [K]
    lab_updated : bool
        A lab result corrected this tick (or, applied late, one before it).
    reasons : tuple of Reason
        The judgements on this tick, in the order the detail gives them.
    clipped : bool
        The published ``moisture_out`` was clipped to its range.
    notes : tuple of str
        What the filter did beyond its routine (covariance matching).
    filter : FilterTerms or None
        The filter's view (model-based estimators that filter).
    blend : Blend or None
        The sources of the published outlet moisture (with the peers).
    window : WindowFacts or None
        What the window held (set by the service's finishing step).
    lab_residual : mapping or None
        Per lab sample id, the lab less the estimate (the open-loop estimator). [kg/kg]
    """

    kind: ClassVar[str] = "estimate"

    window_start_ns: int
    window_end_ns: int
    estimator: str
    moisture_out: float | None
    moisture_out_std: float | None
    moisture_in: float | None
    moisture_in_std: float | None
    T_dryer_out_model: float | None
    T_cyclone_out_model: float | None
    lab_updated: bool = False
    reasons: tuple[Reason, ...] = ()
    clipped: bool = False
    notes: tuple[str, ...] = ()
    filter: FilterTerms | None = None
    blend: Blend | None = None
    window: WindowFacts | None = None
    lab_residual: Mapping[str, float] | None = None

    def __post_init__(self) -> None:
        _none_for_nan(self)

    @property
    def time_ns(self) -> int:
        """When the estimate holds: its window's end [ns]."""
        return self.window_end_ns

    @property
    def status(self) -> str:
        """The worst of its reasons (``ok`` without any)."""
        return worst(*(r.status for r in self.reasons))

    @property
    def detail(self) -> str:
        """Its reasons' sentences in order (the status itself without any)."""
        return "; ".join(r.text for r in self.reasons if r.text) or self.status

    def judged(self, *reasons: Reason, first: bool = False) -> Estimate:
        """This estimate with ``reasons`` added after (``first``: before) its own."""
        return replace(self, reasons=(*reasons, *self.reasons) if first
                       else (*self.reasons, *reasons))

    def to_body(self) -> dict[str, Any]:
        """The ``/softsensor/estimate`` body (CONTRACT section 2 and the project's fields)."""
        body: dict[str, Any] = {k: getattr(self, k) for k in CONTRACT_FIELDS}
        if self.filter is not None:
            body.update(self.filter.to_body())
        body.update(lab_updated=self.lab_updated, clipped=self.clipped, status=self.status,
                    detail=self.detail, window_start_ns=self.window_start_ns,
                    window_end_ns=self.window_end_ns, estimator=self.estimator)
        if self.lab_residual is not None:
            body["lab_residual"] = dict(self.lab_residual)
        if self.blend is not None:
            body.update(self.blend.to_body())
        body["notes"] = list(self.notes)
        if self.window is not None:
            body.update(self.window.to_body())
        return body

    @classmethod
    def from_body(cls, body: Mapping[str, Any]) -> Estimate:
        """The estimate a body describes (its detail as one reason of its status)."""
        b = dict(body)
        status = str(b.get("status") or "ok")
        detail = str(b.get("detail") or "")
        lr = b.get("lab_residual")
        return cls(
            window_start_ns=int(b.get("window_start_ns") or 0),
            window_end_ns=int(b.get("window_end_ns") or 0),
            estimator=str(b.get("estimator", "")),
            **{k: _num(b.get(k)) for k in CONTRACT_FIELDS},
            lab_updated=bool(b.get("lab_updated")),
            reasons=(Reason(status, detail),) if (detail or status != "ok") else (),
            clipped=bool(b.get("clipped")),
            notes=tuple(str(n) for n in b.get("notes") or ()),
            filter=FilterTerms.from_body(b), blend=Blend.from_body(b),
            window=WindowFacts.from_body(b),
            lab_residual=None if lr is None else _frozen_map(
                {str(k): float(v) for k, v in lr.items()}))


@dataclass(frozen=True)
class Stall:
    """The estimator thread is late (the daemon's watchdog): by how long [wall s] and how
    many input messages wait."""

    late_s: float
    pending: int
    window_s: float

    @property
    def reason(self) -> Reason:
        return Reason("stale", f"stalled: no estimate for {self.late_s:.0f} s (one is due "
                               f"every {self.window_s:.0f} s); {self.pending} input messages "
                               f"waiting")


#: The tick's verdict before the first window was ticked, and the inputs' before any scan.
WAITING_FOR_WINDOW = Reason("stale", "waiting for the first complete window")
NO_SCAN_YET = Reason("stale", "no scan received yet")


@dataclass(frozen=True)
class Health:
    """The service's health at ``time_ns`` (module docstring).

    Attributes
    ----------
    time_ns : int
        When it was said [ns].
    unit, estimator : str
        Whose health.
    tick, input, lab : Reason
        The last tick's verdict; the inputs' (a model input without a good value, no scans);
        the lab's (no result accepted for too long).
    counters : mapping of str to int
        The service's counters over its life (scans, ticks, labs accepted and refused, ...).
    window_end_ns, last_scan_ns, last_lab_refusal_ns, last_lab_accepted_ns, stale_since_ns
        The last window ticked, the last scan, the last refusal, the last accepted lab
        result's tick, the start of the last gap cut short [ns] (None: not yet).
    labs_waiting : int
        Lab results waiting for their tick.
    last_lab_refusal : str or None
        Why the latest lab result or file was refused.
    recording : str or None
        The daemon's recorder: ``ok``, why it is paused, None when not recording.
    inputs_dropped, recording_capped : mapping or None
        What the daemon's input limits dropped, and the topics whose daily recording cap was
        reached (bytes), by name.
    stall : Stall or None
        The estimator thread is late (the watchdog).
    resources : str or None
        What the daemon is short of (descriptors near the process limit): ``degraded``.
    """

    kind: ClassVar[str] = "health"

    time_ns: int
    unit: str
    estimator: str
    tick: Reason
    input: Reason
    lab: Reason
    counters: Mapping[str, int] = field(default_factory=dict)
    window_end_ns: int | None = None
    last_scan_ns: int | None = None
    labs_waiting: int = 0
    last_lab_refusal: str | None = None
    last_lab_refusal_ns: int | None = None
    last_lab_accepted_ns: int | None = None
    stale_since_ns: int | None = None
    recording: str | None = None
    inputs_dropped: Mapping[str, int] | None = None
    recording_capped: Mapping[str, int] | None = None
    stall: Stall | None = None
    resources: str | None = None

    @property
    def status(self) -> str:
        """The worst of the tick's, the inputs', the lab's, a stall's and the resources'."""
        return worst(self.tick.status, self.input.status, self.lab.status,
                     *(() if self.stall is None else (self.stall.reason.status,)),
                     *(() if self.resources is None else ("degraded",)))

    @property
    def detail(self) -> str:
        """The tick's verdict when all is well; else what is not, each part saying where."""
        if self.status == "ok":
            parts = [self.tick.text]
        else:
            parts = [] if self.stall is None else [self.stall.reason.text]
            if self.tick.status != "ok":
                parts.append(self.tick.text)
            if self.input.status != "ok":
                parts.append(f"input: {self.input.text}")
            if self.lab.status != "ok":
                parts.append(self.lab.text)
            if self.resources is not None:
                parts.append(f"resources: {self.resources}")
        if self.recording not in (None, "ok"):
            parts.append(f"recording: {self.recording}")
        return "; ".join(parts)

    @classmethod
    def initial(cls, time_ns: int, unit: str, estimator: str) -> Health:
        """The health before any scan or window: ``stale``, waiting for both."""
        return cls(int(time_ns), unit, estimator, tick=WAITING_FOR_WINDOW, input=NO_SCAN_YET,
                   lab=Reason("ok", ""))

    def at(self, time_ns: int, **changes: Any) -> Health:
        """This health said again at ``time_ns`` with ``changes`` (the daemon's news)."""
        return replace(self, time_ns=int(time_ns), **changes)

    def to_body(self) -> dict[str, Any]:
        """The ``/softsensor/health`` body (CONTRACT section 2 and the project's fields)."""
        body: dict[str, Any] = {
            "status": self.status, "detail": self.detail, "tick_status": self.tick.status,
            "input_status": self.input.status, "lab_status": self.lab.status,
            "tick_detail": self.tick.text, "input_detail": self.input.text,
            "lab_detail": self.lab.text,
            "estimator": self.estimator, "unit": self.unit, "window_end_ns": self.window_end_ns,
            "last_scan_ns": self.last_scan_ns, "labs_waiting": self.labs_waiting,
            "last_lab_refusal": self.last_lab_refusal,
            "last_lab_refusal_ns": self.last_lab_refusal_ns,
            "last_lab_accepted_ns": self.last_lab_accepted_ns,
            "stale_since_ns": self.stale_since_ns, **self.counters}
        if self.recording is not None:
            body["recording"] = self.recording
        if self.inputs_dropped is not None:
            body["inputs_dropped"] = dict(self.inputs_dropped)
        if self.recording_capped is not None:
            body["recording_capped"] = dict(self.recording_capped)
        if self.resources is not None:
            body["resources"] = self.resources
        if self.stall is not None:
            body.update(stalled=True, tick_late_s=round(self.stall.late_s, 1),
                        pending=self.stall.pending, tick_every_s=self.stall.window_s)
        return body

    @classmethod
    def from_body(cls, body: Mapping[str, Any], time_ns: int) -> Health:
        """The health a body said at ``time_ns``: its parts from their statuses and details. A
        body that gives only ``status`` and ``detail`` (another program's) reads as the
        tick's verdict."""
        b = dict(body)
        parts = {k: Reason(str(b.get(f"{k}_status") or "ok"), str(b.get(f"{k}_detail") or ""))
                 for k in ("tick", "input", "lab")}
        if not any(f"{k}_detail" in b for k in parts):
            said = str(b.get("status") or "ok")
            parts["tick"] = Reason(worst(said, *(r.status for r in parts.values())),
                                   str(b.get("detail") or ""))
        counters = {k: int(v) for k, v in b.items()
                    if k not in _HEALTH_FIELDS and isinstance(v, int) and not isinstance(v, bool)}

        def opt_int(k: str) -> int | None:
            v = b.get(k)
            return None if v is None else int(v)

        dropped, capped, recording = (b.get(k) for k in ("inputs_dropped", "recording_capped",
                                                          "recording"))
        stall = (Stall(float(b["tick_late_s"]), int(b["pending"]), float(b["tick_every_s"]))
                 if b.get("stalled") else None)
        return cls(int(time_ns), str(b.get("unit", "")), str(b.get("estimator", "")),
                   parts["tick"], parts["input"], parts["lab"], _frozen_map(counters),
                   opt_int("window_end_ns"), opt_int("last_scan_ns"),
                   int(b.get("labs_waiting") or 0),
                   None if b.get("last_lab_refusal") is None else str(b["last_lab_refusal"]),
                   opt_int("last_lab_refusal_ns"), opt_int("last_lab_accepted_ns"),
                   opt_int("stale_since_ns"),
                   None if recording is None else str(recording),
                   None if dropped is None else _frozen_map(dropped),
                   None if capped is None else _frozen_map(capped), stall,
                   None if b.get("resources") is None else str(b["resources"]))


#: The health body's own fields (the rest of its integers are the service's counters).
_HEALTH_FIELDS: frozenset[str] = frozenset({
    "status", "detail", "tick_status", "input_status", "lab_status", "tick_detail",
    "input_detail", "lab_detail", "estimator", "unit",
    "window_end_ns", "last_scan_ns", "labs_waiting", "last_lab_refusal", "last_lab_refusal_ns",
    "last_lab_accepted_ns", "stale_since_ns", "recording", "inputs_dropped",
    "recording_capped", "stalled", "tick_late_s", "pending", "tick_every_s", "resources"})


__all__ = ["CONTRACT_FIELDS", "SEVERITY", "Blend", "Estimate", "FilterTerms", "Health",
           "Reason", "SourceEstimate", "Stall", "WindowFacts", "worst"]
