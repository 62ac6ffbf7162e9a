"""The estimator service, sans I/O: scans and lab results in, estimates and health out.

:class:`EstimatorService` owns a :class:`~softsensor.windows.accumulator.WindowAccumulator`
and an :class:`~softsensor.estimation.interface.Estimator`. It never touches a socket, a file or a
clock: time is whatever the messages say, so the daemon (Zenoh, live), the ``replay`` verb
(offline, in memory or over Zenoh) and the tests drive the very same object and get the very same
estimates.

Events and what they return (a list of :class:`Output`: typed, frozen
:class:`~softsensor.estimate.Estimate` and :class:`~softsensor.estimate.Health`, in publishing
order):

* :meth:`EstimatorService.on_scan` (``/plant/scan`` body, time [ns]): adds the scan to its 600 s
  window; once a scan ``tick_delay_s`` past a window's end has arrived the window is *ticked*: the
  lab results logged up to the window's end are handed to the estimator, the estimator steps over
  the window and an estimate and a health are emitted, both stamped with the window's end.
  Waiting ``tick_delay_s`` makes the order of lab results and ticks a function of the log
  times alone, so a replay of a recorded day reproduces the live estimates exactly.
* :meth:`EstimatorService.on_lab` (``/plant/lab`` body, log time): checked against the lab-result
  contract (:func:`~softsensor.messages.lab_from_body`) and queued until the tick of the window
  holding its log time (:attr:`~softsensor.messages.LabResult.due_ns`): the one queue where lab
  results wait. The estimator gets a result when it is due, so its window is ticking or in
  its history.
* :meth:`EstimatorService.advance` (now [ns]): lets time pass without scans (PLC gone and poller
  silent): windows ``gap_after_s`` past their end are closed (stale) and ticked, and health turns
  ``stale``.
* :meth:`EstimatorService.flush`: end of a recorded day: the partly filled last window is ticked
  too.

Scan values are judged before a window sums them (:mod:`softsensor.windows.plausibility`,
inside the accumulator); every estimator's estimate is finished by one pure step before it goes
out (:func:`finish`): the window's facts added, a stale window's estimate ``stale``, one with a
value outside its physical range
(:func:`~softsensor.windows.plausibility.estimate_problems`) never ``ok`` (published
``degraded`` with the reason first in its ``detail``), the refused inputs said.

Health (CONTRACT section 2) is emitted at every tick, whenever the input state changes
between ticks, and at once when a lab result or a lab file is refused. Its ``status`` is the
worst of the last tick's status (the estimator's verdict: ``ok``, ``degraded`` when its
innovations are inconsistent or the model failed, ``stale`` for a window with too few good
scans), the input status (``degraded`` while a model input has no good value in the latest scan,
``stale`` when no scan came for ``gap_after_s``) and the lab status (``degraded`` when no lab
result was accepted for ``max_lab_silence_s`` of plant time, counted from the last accepted one
or from the first scan: an estimate nobody corrects drifts, and a LIMS that sends only files the
daemon refuses must not look like a quiet lab). A refused lab result (the contract, a flood, the
estimator's screen) and a refused lab file (:meth:`EstimatorService.lab_file_refused`, from the
daemon's lab folder) are counted alike in ``labs_refused`` (files also in ``lab_files_refused``),
and the latest reason is ``last_lab_refusal`` (its time ``last_lab_refusal_ns``).
"""

from __future__ import annotations

import bisect
import dataclasses
import logging
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from softsensor.errors import EstimationError, IngestError, SoftsensorError
from softsensor.estimate import (
    CONTRACT_FIELDS,
    NO_SCAN_YET,
    WAITING_FOR_WINDOW,
    Estimate,
    Health,
    Reason,
    WindowFacts,
    worst,
)
from softsensor.estimation.interface import Estimator, LabResult, Window
from softsensor.estimation.tick_history import (
    lab_from_json,
    lab_to_json,
    window_from_json,
    window_to_json,
)
from softsensor.jsonable import finite_or_none
from softsensor.log_throttle import Throttle, outside_text
from softsensor.messages import SCAN_EXTRA_FIELDS, iso_utc, lab_from_body
from softsensor.service.estimators import estimator_kind
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.accumulator import WindowAccumulator, WindowSettings
from softsensor.windows.plausibility import EstimateRanges, estimate_problems

log = logging.getLogger(__name__)

#: The fields of a scan body the open window keeps (the signals and the scan's own numbers).
_KEPT: frozenset[str] = frozenset(SCAN_SIGNALS) | SCAN_EXTRA_FIELDS

NS = 10**9
_CHECKPOINT_VERSION = 1


#: What the service says: an estimate or a health, each with its ``kind``, ``time_ns`` and
#: ``to_body()`` (:mod:`softsensor.estimate`).
Output = Estimate | Health


@dataclass
class ServiceStats:
    """Counters of a service's life (also in every health body)."""

    scans: int = 0
    bad_scans: int = 0
    ticks: int = 0
    stale_ticks: int = 0
    failed_ticks: int = 0
    lab_updates: int = 0
    labs_received: int = 0
    labs_accepted: int = 0
    labs_refused: int = 0  #: lab results and lab files refused
    lab_files_refused: int = 0  #: of which whole files refused by the daemon's lab folder
    refused_time: int = 0  #: scans and labs stamped too far from the daemon's clock
    skipped_windows: int = 0  #: gap windows not ticked (a gap longer than max_gap_windows)
    unphysical_ticks: int = 0  #: estimates with a value outside its physical range


def finish(estimate: Estimate, window: Window, ranges: EstimateRanges, unit: str
           ) -> tuple[Estimate, list[str]]:
    """The service's last, pure step before an estimate goes out: the window's facts added, a
    stale window's estimate ``stale``, a value outside its physical range never ``ok`` (the
    reason first), the inputs the plausibility limits refused said last. Returns the estimate
    and the fields that were not physical (empty when all were)."""
    facts = WindowFacts(
        unit=unit, n_scans=window.n_scans, stale=window.stale,
        T_dryer_out_measured=_finite(window.means.get("T_dryer_out")),
        T_cyclone_out_measured=_finite(window.means.get("T_cyclone_out")),
        inputs_refused=dict(window.refused),
        inputs_refused_why={name: window.reasons[name] for name in window.refused
                            if name in window.reasons})
    out = replace(estimate, window=facts)
    if window.stale and out.status != "stale":
        out = out.judged(Reason("stale", "stale window"))
    problems = estimate_problems({k: getattr(out, k) for k in CONTRACT_FIELDS}, ranges)
    if problems:
        # whatever the estimator says, a value no dryer can have is not an ok estimate
        out = out.judged(Reason("degraded", "not physical: " + ", ".join(problems)), first=True)
    if window.refused:
        out = out.judged(Reason("ok", "implausible inputs refused: " + ", ".join(
            f"{name} {n}" for name, n in sorted(window.refused.items()))))
    return out, problems


def _finite(v: float | None) -> float | None:
    return None if v is None else finite_or_none(v)


class EstimatorService:
    """Turns scans and lab results into ticks, estimates and health (module docstring).

    Parameters
    ----------
    estimator : Estimator
        The estimator stepped every window (see :mod:`softsensor.service.estimators`).
    window : WindowSettings, optional
        Window length (must equal the model's window), expected scans, thresholds.
    unit : str
        Unit name, copied into the bodies.
    tick_delay_s : float
        Scan time past a window's end at which the window is ticked [s].
    gap_after_s : float
        Silence after which :meth:`advance` closes windows and reports ``stale`` [s].
    max_gap_windows : int
        Of a longer gap only the last this many windows are ticked (stale); the rest is one
        "stale since" state in health, so one scan stamped far ahead costs bounded work.
    ranges : EstimateRanges, optional
        Physical range of each estimate field; an estimate outside is never ``ok``.
    max_lab_silence_s : float, optional
        Health is ``degraded`` once no lab result was accepted for this long [plant s];
        None: never (module docstring).
    time_gate : callable, optional
        Refuses message times far from the service's clock: the reason, or None (the daemon
        passes a :class:`~softsensor.service.time_gate.TimeGate`; a replay has no clock).
    max_pending_labs : int
        Lab results that may wait for one tick; more are refused (a flood).
    """

    def __init__(self, estimator: Estimator, window: WindowSettings | None = None, *,
                 unit: str = "dryer1", tick_delay_s: float = 10.0,
                 gap_after_s: float = 60.0, max_gap_windows: int = 36,
                 ranges: EstimateRanges | None = None,
                 max_lab_silence_s: float | None = None,
                 time_gate: Callable[[int], str | None] | None = None,
                 max_pending_labs: int = 50) -> None:
        self.estimator = estimator
        self.max_lab_silence_ns = (None if max_lab_silence_s is None
                                   else int(round(max_lab_silence_s * NS)))
        self.ranges = ranges or EstimateRanges()
        self.kind = estimator_kind(estimator)
        self.window = window or WindowSettings()
        self.unit = unit
        self.tick_delay_ns = int(round(tick_delay_s * NS))
        self.gap_after_ns = int(round(gap_after_s * NS))
        self.stats = ServiceStats()
        self.max_gap_windows = int(max_gap_windows)
        self._acc = WindowAccumulator(self.window, max_gap_windows=self.max_gap_windows)
        self._window_scans: list[tuple[int, dict[str, Any]]] = []  # scans of the open window
        self._ready: deque[Window] = deque()
        self._labs: list[LabResult] = []  # the one queue: waiting for their tick (due order)
        self._closed_end: int | None = None  # end of the last window the accumulator closed
        self._ticked_end: int | None = None
        self._last_scan: int | None = None
        self._now: int | None = None
        self._tick_status: Reason | None = None
        self._input_status = NO_SCAN_YET
        self._input_key: tuple[str, tuple[str, ...]] = ("stale", ())
        self._published: tuple[str, tuple[str, ...]] | None = None
        self._last_refusal: str | None = None
        self._last_refusal_ns: int | None = None
        #: the last accepted lab result's tick, or the first scan: where lab silence counts from
        self._lab_since: int | None = None
        self._stale_since: int | None = None  # start of the last gap cut short
        self._skipped_seen = 0  # gap windows of self._acc already counted in the stats
        self.time_gate = time_gate
        self.max_pending_labs = int(max_pending_labs)
        self._throttle = Throttle()  # bad scans from a broken peer: a few lines, counted
        #: called with the sample id of every lab result refused (the estimator's envelope
        #: or screen, a flood): the daemon's lab input frees the id for a corrected result
        self.on_lab_refused: Callable[[str], None] | None = None
        #: a throwaway service on made-up data (the daemon's warm-up): its lines say so
        self.synthetic = False

    # ------------------------------------------------------------------ events
    def on_message(self, kind: str, body: Mapping[str, Any], time_ns: int | None) -> list[Output]:
        """Dispatch a bus message of ``kind`` ``scan`` or ``lab`` (others are ignored)."""
        if kind == "scan":
            if time_ns is None:
                self.stats.bad_scans += 1
                self._throttle.log(log, "no time", logging.WARNING,
                                   "scan without time_ns ignored (%d bad scans so far)",
                                   self.stats.bad_scans)
                return []
            return self.on_scan(time_ns, body)
        if kind == "lab":
            return self.on_lab(body, time_ns)
        return []

    def _implausible(self, what: str, t: int) -> bool:
        """Refuse (count, log the first and every 1000th) a time the gate refuses."""
        reason = None if self.time_gate is None else self.time_gate(t)
        if reason is None:
            return False
        self.stats.refused_time += 1
        if self.stats.refused_time % 1000 == 1:
            log.warning("%s at %d ns refused: %s (%d refused so far)", what, t, reason,
                        self.stats.refused_time)
        return True

    def on_scan(self, time_ns: int, body: Mapping[str, Any]) -> list[Output]:
        """Add one ``/plant/scan`` body (SI, null = bad) logged at ``time_ns`` [ns]."""
        t = int(time_ns)
        if self._implausible("scan", t):
            return []
        try:
            closed = self._acc.add(t, body)
        except IngestError as exc:
            self.stats.bad_scans += 1
            self._throttle.log(log, "bad scan", logging.WARNING,
                               "scan at %d ns ignored: %s (%d bad scans so far)", t,
                               outside_text(exc), self.stats.bad_scans)
            return []
        if closed:
            self._window_scans = []
        # what the window needs again (on a restore), not what else a scan carried: a peer's
        # 60 kB of padding must not be kept, checkpointed and written again every tick
        self._window_scans.append((t, {k: v for k, v in body.items() if k in _KEPT}))
        self.stats.scans += 1
        self._last_scan = t if self._last_scan is None else max(self._last_scan, t)
        self._now = t if self._now is None else max(self._now, t)
        if self._lab_since is None:
            self._lab_since = t
        self._queue(closed)
        self._set_input(*self._input_of(body))
        out = self._drain(self._now - self.tick_delay_ns)
        return self._with_health_change(out, t)

    def on_lab(self, body: Mapping[str, Any], log_time_ns: int | None) -> list[Output]:
        """Check one ``/plant/lab`` body logged at ``log_time_ns`` and queue it for its tick."""
        self.stats.labs_received += 1
        if log_time_ns is not None and self._implausible("lab", int(log_time_ns)):
            return []
        t = log_time_ns if log_time_ns is not None else self._now
        try:
            lab = lab_from_body(dict(body), t, where=f"plant/{self.unit}/lab")
        except IngestError as exc:
            return self._refused(str(exc), t)
        if len(self._labs) >= self.max_pending_labs:
            # a lab sends a few results a day; thousands waiting for one tick are a flood
            # (each would cost the filter an update) and would starve the estimator thread
            self._free(lab.sample_id)
            return self._refused(f"lab result {lab.sample_id!r} refused: {len(self._labs)} "
                                 f"results already wait for the next tick (at most "
                                 f"{self.max_pending_labs})", t)
        bisect.insort(self._labs, lab, key=lambda r: (r.due_ns, r.sample_id))
        return []

    def lab_file_refused(self, reason: str, time_ns: int | None) -> list[Output]:
        """A lab file the daemon's folder refused whole (``reason``: its one line), at
        ``time_ns`` [ns, the daemon's clock]: counted and told in health at once."""
        self.stats.lab_files_refused += 1
        return self._refused(f"lab file refused: {reason}", time_ns)

    def _refused(self, reason: str, time_ns: int | None) -> list[Output]:
        """Count and remember a refusal; the health body that says so (none before the
        service has a time: nothing was heard yet)."""
        t = time_ns if time_ns is not None else self._now
        self._refuse(reason, t)
        return [] if t is None else [self._health(int(t))]

    def advance(self, now_ns: int) -> list[Output]:
        """Let time pass to ``now_ns`` [ns] without scans (live only; see module docstring)."""
        now = int(now_ns)
        self._now = now if self._now is None else max(self._now, now)
        closed = self._acc.advance(now - self.gap_after_ns)
        if closed:
            self._window_scans = []
        self._queue(closed)
        out = self._drain(now - self.gap_after_ns)
        if self._last_scan is None or now - self._last_scan > self.gap_after_ns:
            since = ("since start" if self._last_scan is None else
                     f"for {(now - self._last_scan) / NS:.0f} s")
            self._set_input("stale", f"no scans {since}", ("no_scans",))
        return self._with_health_change(out, now)

    def flush(self) -> list[Output]:
        """Close and tick every window left, the partly filled last one included."""
        closed = self._acc.flush()
        if closed:
            self._window_scans = []
        self._queue(closed)
        return self._drain(None)

    # ------------------------------------------------------------------ internals
    def _queue(self, windows: list[Window]) -> None:
        # the accumulator counts since it was made (a restore makes a new one); the stats
        # count over the service's life, checkpoints included
        skipped = self._acc.n_skipped - self._skipped_seen
        if skipped > 0 and self._acc.stale_since_ns is not None:
            self._skipped_seen = self._acc.n_skipped
            self.stats.skipped_windows += skipped
            self._stale_since = self._acc.stale_since_ns
            log.warning("a gap of %d windows since %s: the last %d are ticked, %d skipped",
                        skipped + self.max_gap_windows, iso_utc(self._stale_since),
                        self.max_gap_windows, skipped)
        for w in windows:
            self._ready.append(w)
            self._closed_end = w.end_ns

    def _drain(self, until_ns: int | None) -> list[Output]:
        """Tick the ready windows that end at or before ``until_ns`` (None: all)."""
        out: list[Output] = []
        while self._ready and (until_ns is None or self._ready[0].end_ns <= until_ns):
            out.extend(self._tick(self._ready.popleft()))
        return out

    def _tick(self, window: Window) -> list[Output]:
        due = [lab for lab in self._labs if lab.due_ns <= window.end_ns]
        self._labs = self._labs[len(due):]
        for lab in due:
            try:
                reason = self.estimator.add_lab(lab)
            except SoftsensorError as exc:
                reason = f"lab {lab.sample_id!r}: {exc}"
            if reason is None:
                self.stats.labs_accepted += 1
                self._lab_since = window.end_ns
                if self.synthetic:  # the warm-up's made-up result: no plant lab was taken
                    log.debug("warm-up: the synthetic lab result (moisture_out %.4f kg/kg, "
                              "made up at %s) compiled the lab update; not a plant result",
                              lab.moisture_out, iso_utc(lab.sample_time_ns))
                else:
                    log.info("lab %s accepted: moisture_out %.4f kg/kg sampled at %s",
                             outside_text(lab.sample_id), lab.moisture_out,
                             iso_utc(lab.sample_time_ns))
            else:
                self._refuse(reason, window.end_ns)
                self._free(lab.sample_id)
        self._ticked_end = window.end_ns
        try:
            estimate = self.estimator.tick(window)
        except (SoftsensorError, ArithmeticError, ValueError) as exc:
            self.stats.failed_ticks += 1
            detail = f"estimator failed at the window ending {window.end_ns} ns: {exc}"
            log.error("%s", detail)
            self._tick_status = Reason("degraded", detail)
            return [self._health(window.end_ns)]
        estimate, problems = finish(estimate, window, self.ranges, self.unit)
        self.stats.ticks += 1
        if window.stale:
            self.stats.stale_ticks += 1
        if estimate.lab_updated:
            self.stats.lab_updates += 1
        if problems:
            self.stats.unphysical_ticks += 1
        self._tick_status = Reason(estimate.status, estimate.detail)
        return [estimate, self._health(window.end_ns)]

    def _free(self, sample_id: str) -> None:
        """Tell :attr:`on_lab_refused` that ``sample_id`` was not taken."""
        if self.on_lab_refused is None:
            return
        try:
            self.on_lab_refused(sample_id)
        except Exception:  # noqa: BLE001 - the refusal stands; the news must not undo it
            self._throttle.log(log, "freeing", logging.ERROR,
                               "freeing a refused lab sample id failed", exc_info=True)

    def _refuse(self, reason: str, time_ns: int | None) -> None:
        reason = outside_text(reason)  # a sample id or a value from outside, cut short
        self.stats.labs_refused += 1
        self._last_refusal = reason
        self._last_refusal_ns = time_ns
        n = self.stats.labs_refused
        if n <= 10 or n % 1000 == 0:  # a flood must not become a flood of log lines
            log.warning("lab refused: %s (%d refused so far)", reason, n)

    def _input_of(self, body: Mapping[str, Any]) -> tuple[str, str, tuple[str, ...]]:
        """Input status of one scan: ``degraded`` while a model input has no good value."""
        missing = []
        for name in self.window.required:
            v = body.get(name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                missing.append(name)
        if not missing:
            return "ok", "every model input read", ()
        quality = body.get("quality")
        reasons = quality if isinstance(quality, Mapping) else {}
        parts = [f"{n} ({reasons[n]})" if n in reasons else n for n in missing]
        return "degraded", "no good value of " + ", ".join(parts), tuple(missing)

    def _set_input(self, status: str, detail: str, key: tuple[str, ...]) -> None:
        self._input_status = Reason(status, detail)
        self._input_key = (status, key)

    def _lab_status(self, now_ns: int | None) -> Reason:
        """``degraded`` when no lab result was accepted for ``max_lab_silence_s`` by
        ``now_ns`` (module docstring), with the hours and the last refusal; else ``ok``."""
        if self.max_lab_silence_ns is None or self._lab_since is None or now_ns is None:
            return Reason("ok", "")
        silent = now_ns - self._lab_since
        if silent <= self.max_lab_silence_ns:
            return Reason("ok", "")
        since = "the first scan" if self.stats.labs_accepted == 0 else "the last one"
        detail = (f"lab: no lab result accepted for {silent / 3600 / NS:.1f} h since {since} "
                  f"(service.max_lab_silence_h {self.max_lab_silence_ns / 3600 / NS:g}): the "
                  f"estimate is uncorrected")
        if self._last_refusal is not None:
            detail += f"; last lab refusal: {self._last_refusal}"
        return Reason("degraded", detail)

    def _state_key(self) -> tuple[str, tuple[str, ...]]:
        tick = self._tick_status.status if self._tick_status else "stale"
        lab = self._lab_status(self._now).status
        return (worst(tick, self._input_key[0], lab), (tick, lab, *self._input_key[1]))

    def _with_health_change(self, out: list[Output], time_ns: int) -> list[Output]:
        """Append a health body when the state changed since the last one published."""
        if any(o.kind == "health" for o in out) or self._state_key() == self._published:
            return out
        if self._tick_status is None and self._published is None \
                and self._input_key[0] == "stale":
            return out  # nothing to say before the first scan
        return [*out, self._health(time_ns)]

    def _health(self, time_ns: int) -> Health:
        self._published = self._state_key()
        return Health(
            time_ns=int(time_ns), unit=self.unit, estimator=self.kind,
            tick=self._tick_status or WAITING_FOR_WINDOW,
            input=self._input_status,
            lab=self._lab_status(max(int(time_ns), self._now or 0)),
            counters=dataclasses.asdict(self.stats), window_end_ns=self._ticked_end,
            last_scan_ns=self._last_scan, labs_waiting=len(self._labs),
            last_lab_refusal=self._last_refusal, last_lab_refusal_ns=self._last_refusal_ns,
            last_lab_accepted_ns=self._lab_since if self.stats.labs_accepted else None,
            stale_since_ns=self._stale_since)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self) -> dict[str, Any]:
        """JSON-able snapshot from which :meth:`restore` continues (estimator included)."""
        return {
            "version": _CHECKPOINT_VERSION, "estimator_kind": self.kind, "unit": self.unit,
            "estimator": self.estimator.checkpoint(), "closed_end_ns": self._closed_end,
            "ticked_end_ns": self._ticked_end, "last_scan_ns": self._last_scan,
            "now_ns": self._now, "ready": [window_to_json(w) for w in self._ready],
            "window_scans": [[t, b] for t, b in self._window_scans],
            "judge": self._acc.judge_state_at_window_start,
            "labs": [lab_to_json(r) for r in self._labs],
            "tick_status": ([self._tick_status.status, self._tick_status.text]
                            if self._tick_status else None),
            "stats": dataclasses.asdict(self.stats),
            "lab_since_ns": self._lab_since, "last_lab_refusal": self._last_refusal,
            "last_lab_refusal_ns": self._last_refusal_ns,
        }

    def restore(self, snapshot: Mapping[str, Any], where: str = "checkpoint") -> None:
        """Continue from :meth:`checkpoint` output, the scans of the open window included.

        Raises :class:`EstimationError` naming ``where`` when the snapshot is of another
        version or estimator kind, or malformed.
        """
        if snapshot.get("version") != _CHECKPOINT_VERSION:
            raise EstimationError(f"{where}: version {snapshot.get('version')!r}, expected "
                                  f"{_CHECKPOINT_VERSION}")
        if snapshot.get("estimator_kind") != self.kind:
            raise EstimationError(f"{where}: written by estimator "
                                  f"{snapshot.get('estimator_kind')!r}, this run uses "
                                  f"{self.kind!r}")
        try:
            self.estimator.restore(snapshot["estimator"])
            closed = snapshot["closed_end_ns"]
            self._closed_end = None if closed is None else int(closed)
            ticked = snapshot["ticked_end_ns"]
            self._ticked_end = None if ticked is None else int(ticked)
            last = snapshot["last_scan_ns"]
            self._last_scan = None if last is None else int(last)
            now = snapshot["now_ns"]
            self._now = None if now is None else int(now)
            self._ready = deque(window_from_json(w) for w in snapshot["ready"])
            self._window_scans = [(int(t), dict(b)) for t, b in snapshot["window_scans"]]
            self._labs = [lab_from_json(r) for r in snapshot["labs"]]
            tick = snapshot["tick_status"]
            self._tick_status = None if tick is None else Reason(str(tick[0]), str(tick[1]))
            self.stats = ServiceStats(**{k: int(v) for k, v in snapshot["stats"].items()})
            # (absent from the checkpoints of earlier daemons: the lab clock starts again)
            since = snapshot.get("lab_since_ns")
            self._lab_since = None if since is None else int(since)
            refusal = snapshot.get("last_lab_refusal")
            self._last_refusal = None if refusal is None else str(refusal)
            refused_at = snapshot.get("last_lab_refusal_ns")
            self._last_refusal_ns = None if refused_at is None else int(refused_at)
            # the open window, fed again to an accumulator whose judge remembers what it did
            # at the window's start: its scans are judged (and refused) as they were live
            self._acc = WindowAccumulator(self.window, start_ns=self._closed_end,
                                          max_gap_windows=self.max_gap_windows,
                                          judge_state=snapshot.get("judge"))
            for t, body in self._window_scans:
                self._acc.add(t, body)
        except EstimationError as exc:
            raise EstimationError(f"{where}: {exc}") from exc
        except (KeyError, TypeError, ValueError, IndexError, ArithmeticError,
                SoftsensorError) as exc:
            raise EstimationError(f"{where}: malformed checkpoint ({exc!r})") from exc
        self._skipped_seen = 0

    # ------------------------------------------------------------------ views
    @property
    def now_ns(self) -> int | None:
        """Latest time seen in a scan or :meth:`advance` [ns]."""
        return self._now

    @property
    def ticked_end_ns(self) -> int | None:
        """End of the last window ticked [ns]."""
        return self._ticked_end

    @property
    def last_lab_refusal(self) -> str | None:
        """Why the latest lab result or lab file was refused (None: none was)."""
        return self._last_refusal

    @property
    def late_scans(self) -> int:
        """Scans that arrived for a window already closed (dropped)."""
        return self._acc.n_late


__all__ = ["EstimatorService", "Output", "ServiceStats"]
