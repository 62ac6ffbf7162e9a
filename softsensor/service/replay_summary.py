"""What a replay did: its counts, its speed, its estimates, and their error against the truth
a virtual plant recorded (for reporting only; the estimator never sees it).

:class:`ReplaySummary` is what :func:`~softsensor.service.offline_replay.replay_to_file`
returns and what ``softsensor replay`` prints (:meth:`ReplaySummary.line`), with one
:class:`DayPart` per day of a several-day replay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.service.day_replay import ReplayStats
from softsensor.service.estimator_service import ServiceStats


@dataclass
class ReplaySummary:
    """What a replay did. Times in ns since the epoch, durations in seconds.

    ``wall_s`` is the streaming alone; ``warmup_s`` the estimator's warm-up before it
    (:mod:`.warmup`: numba compiling or loading its kernels).
    """

    day: Path
    out: Path
    estimator: str
    scan_period_s: float = math.nan
    min_good: int = 0
    expected_scans: int = 0
    n_replayed: int = 0
    n_recorded: int = 0
    ticks: int = 0
    stale_ticks: int = 0
    lab_updates: int = 0
    labs_accepted: int = 0
    labs_refused: int = 0
    span_s: float = 0.0
    wall_s: float = 0.0
    warmup_s: float = 0.0
    rmse: dict[str, float] | None = None
    #: values per signal the plausibility limits refused, over the whole day
    inputs_refused: dict[str, int] = field(default_factory=dict)
    #: per signal, the first window's reason (the first value refused and the limits)
    inputs_refused_why: dict[str, str] = field(default_factory=dict)
    estimates: list[tuple[int, dict[str, Any]]] = field(default_factory=list, repr=False)
    parts: list[DayPart] = field(default_factory=list)

    @property
    def speedup(self) -> float:
        """Recorded time span over wall time [-]."""
        return self.span_s / self.wall_s if self.wall_s > 0 else math.inf

    def tally(self, now: ServiceStats, before: ServiceStats, stats: ReplayStats,
              n_recorded: int) -> None:
        """The replay's counts: the service's since ``before``, what was replayed and
        recorded, and the inputs the plausibility limits refused over the estimates."""
        self.n_replayed = stats.n_published
        self.n_recorded = n_recorded
        self.ticks, self.stale_ticks = now.ticks - before.ticks, \
            now.stale_ticks - before.stale_ticks
        self.lab_updates = now.lab_updates - before.lab_updates
        self.labs_accepted = now.labs_accepted - before.labs_accepted
        self.labs_refused = now.labs_refused - before.labs_refused
        for _t, body in self.estimates:
            for name, n in (body.get("inputs_refused") or {}).items():
                self.inputs_refused[name] = self.inputs_refused.get(name, 0) + int(n)
            for name, why in (body.get("inputs_refused_why") or {}).items():
                self.inputs_refused_why.setdefault(name, str(why))
        if stats.first_ns is not None and stats.last_ns is not None:
            self.span_s = (stats.last_ns - stats.first_ns) / 1e9

    def score(self, truths: dict[Path, list[tuple[int, float, float]]]) -> None:
        """Each day's estimates (window ends from its first message to the next day's) and,
        with the days' ``/truth/plant`` values (``truths``, by day; empty when not reported),
        the RMSE of all estimates and of each day's."""
        if truths:
            self.rmse = truth_rmse([x for truth in truths.values() for x in truth],
                                   self.estimates)
        parts = [p for p in self.parts if p.first_ns is not None]
        for i, part in enumerate(parts):
            lo = part.first_ns
            hi = parts[i + 1].first_ns if i + 1 < len(parts) else None
            mine = [(t, b) for t, b in self.estimates if t > lo and (hi is None or t <= hi)]
            part.ticks = len(mine)
            if part.day in truths:
                part.rmse = truth_rmse(truths[part.day], mine)

    def problem(self) -> tuple[str, str] | None:
        """``("error", why)`` when no tick was estimated from data (every window stale),
        ``("warning", why)`` when more than half were stale, else None."""
        if self.ticks == 0:
            return "error", f"{self.day}: no window was ticked (is the day shorter than one?)"
        share = self.stale_ticks / self.ticks
        if share < 0.5:
            return None
        refused = self._refused_inputs()
        if refused:
            why = f"{self.stale_ticks} of {self.ticks} windows stale: {refused}"
        else:
            why = (f"{self.stale_ticks} of {self.ticks} windows stale: a window needs "
                   f"{self.min_good} good scans of every model input out of the "
                   f"{self.expected_scans} expected at the scan period {self.scan_period_s:g} "
                   f"s (set solver.scan_period if that is not the day's)")
        if self.stale_ticks == self.ticks:
            return "error", f"{self.day}: nothing estimated from data, {why}"
        return "warning", f"{self.day}: {why}"

    def _refused_inputs(self) -> str | None:
        """The inputs the plausibility limits refused in more than half the scans of the day
        expected (what made its windows stale), with why; None when none was."""
        n_scans = self.ticks * self.expected_scans
        many = {k: n for k, n in self.inputs_refused.items() if n > 0.5 * n_scans}
        if not many:
            return None
        parts = "; ".join(f"{k}: {n} values refused ({self.inputs_refused_why.get(k, '')})"
                          for k, n in sorted(many.items(), key=lambda kv: -kv[1]))
        first = max(many, key=many.__getitem__)
        return (f"the plausibility limits refused the inputs: {parts} (is the unit of {first} "
                f"right? softsensor import --preview holds an export against the limits; if "
                f"the plant runs there, set [plausibility.{first}] in the plant config)")

    def line(self) -> str:
        """The one-paragraph summary the verb prints."""
        text = (f"replayed {self.day}: {self.n_replayed} messages over {self.span_s / 3600:.1f} "
                f"h (scan period {self.scan_period_s:g} s) in {self.wall_s:.1f} s "
                f"({self.speedup:,.0f}x real time, after a "
                f"{self.warmup_s:.1f} s warm-up); {self.estimator}: "
                f"{self.ticks} ticks ({self.stale_ticks} stale), {self.lab_updates} lab "
                f"updates ({self.labs_accepted} lab results accepted, {self.labs_refused} "
                f"refused); wrote {self.out} ({self.n_recorded} messages)")
        if self.rmse:
            parts = ", ".join(f"{k} {v:.4f}" for k, v in self.rmse.items())
            text += f"; RMSE against /truth/plant (reporting only): {parts} kg/kg"
        if len(self.parts) > 1:
            text += "; per day: " + "; ".join(p.line() for p in self.parts)
        return text


@dataclass
class DayPart:
    """One day of a several-day replay: its messages, their log-time span, the estimates
    whose window ends fall in it (up to the next day's first message) and their RMSE against
    the day's ``/truth/plant``."""

    day: Path
    n_replayed: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    ticks: int = 0
    rmse: dict[str, float] | None = None

    def line(self) -> str:
        hours = 0.0 if self.first_ns is None or self.last_ns is None \
            else (self.last_ns - self.first_ns) / 3.6e12
        text = f"{self.day}: {self.n_replayed} messages over {hours:.1f} h, {self.ticks} ticks"
        if self.rmse:
            text += " (RMSE " + ", ".join(f"{k} {v:.4f}" for k, v in self.rmse.items()) + ")"
        return text


def truth_rmse(truth: list[tuple[int, float, float]],
               estimates: list[tuple[int, dict[str, Any]]],
               max_age_s: float = 60.0) -> dict[str, float] | None:
    """RMSE of ``moisture_out`` and ``moisture_in`` estimates against the ``/truth/plant``
    values ``(time, moisture_out, moisture_in)``
    (:attr:`~softsensor.service.offline_replay.DayStream.truth`).

    Each estimate (window end ``t``) is compared with the last truth value at or before ``t``
    no older than ``max_age_s``. None when the day has no truth. For reporting only.
    """
    if not truth:
        return None
    tt = np.asarray([t for t, _, _ in truth], dtype=np.int64)
    values = np.asarray([(mo, mi) for _, mo, mi in truth], dtype=float)
    out: dict[str, float] = {}
    for j, name in enumerate(("moisture_out", "moisture_in")):
        err = []
        for t, body in estimates:
            v = body.get(name)
            i = int(np.searchsorted(tt, t, side="right")) - 1
            if v is None or i < 0 or t - tt[i] > max_age_s * 1e9 \
                    or not math.isfinite(values[i, j]):
                continue
            err.append(float(v) - values[i, j])
        if err:
            out[name] = float(np.sqrt(np.mean(np.square(err))))
    return out or None


__all__ = ["DayPart", "ReplaySummary", "truth_rmse"]
