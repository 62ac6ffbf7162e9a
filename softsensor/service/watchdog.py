"""The daemon's watchdog and its health queryable.

The estimator thread ticks once a window (600 plant seconds): on a scan ``tick_delay_s`` past
the window's end or, with the PLC silent, ``gap_after_s`` past it. A thread that is stuck or
starved misses that. :class:`Watchdog`, run from the daemon's housekeeping loop (another
thread), sees no estimate for more than one window past the latest a tick can come, and then
has health published: ``status = "stale"`` (CONTRACT section 2 keeps to ``ok``,
``degraded``, ``stale``) with ``stalled = true`` and a detail saying how late and how many
messages wait; again every window while it lasts. The daemon puts it through the worker's
one path to the bus and the outputs (:meth:`~softsensor.service.bus_worker.BusWorker.
publish_aside`), one message at a time with the estimator thread's.

:class:`HealthQueryable` answers a Zenoh ``get`` on ``softsensor/<unit>/health`` at any time
with the latest health, the watchdog's verdict and the input counters, so a container health
check or an operator's script need not wait up to a window for the next publication
(``softsensor health``).

Only the daemon may answer: its access control refuses a queryable or reply on its keys from
any other session (:func:`~softsensor.bus.zenoh_bus.output_guard_acl`), and
:func:`query_health` takes every reply, not Zenoh's consolidated latest, and gives an answer
only when exactly one session answered and it is the one the client is connected to (the
daemon's endpoint); otherwise it says why it cannot tell.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from softsensor.estimate import Stall
from softsensor.log_throttle import Throttle
from softsensor.service.logs import event

log = logging.getLogger(__name__)

NS = 10**9


class Watchdog:
    """Says when the estimator thread is late (module docstring).

    Parameters
    ----------
    window_wall_s : float
        A window in wall seconds (600 / ``time_scale``).
    grace_wall_s : float
        Longest normal wait after a window's end for its tick [wall s] (``gap_after_s`` and
        ``tick_delay_s`` scaled).
    last_tick_at : callable
        ``time.monotonic()`` of the last estimate published.
    pending : callable
        Input messages waiting for the thread.
    first_input_at : callable, optional
        ``time.monotonic()`` of the first input message the worker queued, None before one.
        Given, the first estimate is awaited from it, with one window more (issue 49: on a
        normal start the ERROR ``estimator_stalled`` came before the first window, the wait
        measured from before the outputs and the PLC connection were up): before any input
        there is nothing the estimator could be late with (the input's health says "no
        scans"), and the first window closes up to one window after the first scan.
    """

    def __init__(self, window_wall_s: float, grace_wall_s: float,
                 last_tick_at: Callable[[], float], pending: Callable[[], int],
                 first_input_at: Callable[[], float | None] | None = None) -> None:
        self.window_wall_s = float(window_wall_s)
        self.limit_s = 2.0 * self.window_wall_s + float(grace_wall_s)
        self._last_tick_at = last_tick_at
        self._pending = pending
        self._first_input_at = first_input_at
        self._start_mark = last_tick_at()  # unchanged until the first estimate goes out
        self.stalled = False
        self.n_stalls = 0
        self._announced: float | None = None

    def _lateness(self, now: float) -> tuple[float, float] | None:
        """How late the next estimate is and the limit it is held to; None when no estimate
        is due yet (no input before the first one)."""
        last = self._last_tick_at()
        if self._first_input_at is None or last != self._start_mark:
            return now - last, self.limit_s
        first = self._first_input_at()
        if first is None:
            return None
        return now - first, self.limit_s + self.window_wall_s

    def check(self, now: float | None = None) -> Stall | None:
        """The stall to say when one is due now, else None."""
        now = time.monotonic() if now is None else now
        due = self._lateness(now)
        late, limit = (0.0, math.inf) if due is None else due
        if late <= limit:
            if self.stalled:
                event(log, "estimator_recovered", late_s=round(late, 1))
            self.stalled, self._announced = False, None
            return None
        if self._announced is not None and now - self._announced < self.window_wall_s:
            return None
        if not self.stalled:
            self.n_stalls += 1
        self.stalled, self._announced = True, now
        pending = self._pending()
        event(log, "estimator_stalled", logging.ERROR, late_s=round(late, 1), pending=pending)
        return Stall(late, pending, self.window_wall_s)


class HealthQueryable:
    """Answers ``get softsensor/<unit>/health`` with what ``answer`` returns at the time of the
    query (the daemon's latest health with the watchdog's verdict and the input counters;
    module docstring)."""

    def __init__(self, session: zenoh.Session, unit: str,
                 answer: Callable[[], dict[str, Any]]) -> None:
        self.key = f"softsensor/{unit}/health"
        self._answer_now = answer
        self._throttle = Throttle()  # a failing answer, asked in a loop, said once a while
        self._queryable = session.declare_queryable(self.key, self._answer)

    def _answer(self, query: zenoh.Query) -> None:
        try:
            doc = dict(self._answer_now())
            doc["answered_ns"] = time.time_ns()
            query.reply(self.key, json.dumps(doc, allow_nan=False, default=str).encode())
        except Exception:  # noqa: BLE001 - must not escape into zenoh's thread
            self._throttle.log(log, "answer", logging.ERROR, "health query not answered",
                               exc_info=True)

    def close(self) -> None:
        """Undeclare the queryable (idempotent)."""
        q, self._queryable = self._queryable, None
        if q is not None:
            try:
                q.undeclare()
            except zenoh.ZError:  # session already closed
                pass


@dataclass(frozen=True)
class HealthAnswer:
    """What :func:`query_health` learned: the daemon's answer, or why there is none."""

    doc: dict[str, Any] | None
    problem: str | None = None
    replier: str | None = None  #: Zenoh id of the session that answered


def _zid(reply: zenoh.Reply) -> str | None:
    rid = reply.replier_id
    return None if rid is None else str(rid.zid)


def query_health(session: zenoh.Session, unit: str, timeout_s: float = 5.0) -> HealthAnswer:
    """Ask ``softsensor/<unit>/health`` and attribute the answer (module docstring)."""
    key = f"softsensor/{unit}/health"
    answers: dict[str | None, dict[str, Any]] = {}
    for reply in session.get(key, timeout=timeout_s,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is None:
            continue
        try:
            doc = json.loads(reply.ok.payload.to_bytes())
        except ValueError:
            doc = None
        answers[_zid(reply)] = doc if isinstance(doc, dict) else {}
    if not answers:
        return HealthAnswer(None, f"no answer within {timeout_s:g} s")
    if len(answers) > 1:
        return HealthAnswer(None, f"{len(answers)} sessions answered on {key}: cannot tell "
                                  f"which is the daemon (another peer answers in its name)")
    (replier, doc), = answers.items()
    direct = {str(z) for z in session.info.peers_zid()}
    if replier is None or replier not in direct:
        return HealthAnswer(None, f"the answer came from session {replier}, not from the "
                                  f"session this client is connected to: cannot tell it is "
                                  f"the daemon (connect to the daemon's own endpoint)",
                            replier)
    if not doc:
        return HealthAnswer(None, "the daemon's answer is not a JSON object", replier)
    return HealthAnswer(doc, None, replier)


__all__ = ["HealthAnswer", "HealthQueryable", "Watchdog", "query_health"]
