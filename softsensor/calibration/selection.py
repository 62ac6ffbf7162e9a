"""Choosing the calibration window(s) in a long record (the paper's data-selection strategy).

Closed-loop production data carry no deliberate excitation; the paper calibrates on the
periods with the most *natural variability*. For every candidate window of the requested
length (stepped by :data:`STEP_HOURS`), each varying signal's standard deviation of its
600 s means inside the window is divided by its standard deviation over the whole record;
the window's score is the sum over signals. A signal that moves more in the window than it
does on average (a production change, a set-point move, the daily ambient swing) adds more
than 1. Signals: the measured model inputs plus the two outlet temperatures (a set-point move
only shows there). Signals that do not vary over the record (std below their noise) score 0.
Candidates with fewer than ``min_labs`` lab samples are skipped: without lab results the
moisture channel cannot be fitted. Several windows are picked greedily without overlap.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from softsensor.calibration.dataset import (
    MEASURED_INPUTS,
    SCANNED_OUTPUTS,
    DayLike,
    Segment,
    segment_from_day,
)
from softsensor.errors import IngestError
from softsensor.messages import iso_utc
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES

#: The paper's calibration horizon [h].
DEFAULT_WINDOW_HOURS = 48.0
#: Lab samples a calibration window must hold.
DEFAULT_MIN_LABS = 3


@dataclass(frozen=True)
class DataSelection:
    """How the calibration data are taken from the recorded days."""

    window_hours: float = DEFAULT_WINDOW_HOURS
    windows_per_day: int = 1
    min_labs: int = DEFAULT_MIN_LABS

#: Candidate windows start every this many hours.
STEP_HOURS = 1.0
#: Signals whose variability is scored.
SCORED_SIGNALS: tuple[str, ...] = MEASURED_INPUTS + SCANNED_OUTPUTS
#: Below this record-wide std a signal counts as constant (SI units of each signal).
CONSTANT_BELOW = {"T_air_in": 0.05, "m_air": 1e-3, "m_fiber": 1e-4, "T_fiber_in": 0.05,
                  "m_steam": 1e-5, "T_amb": 0.05, "H_amb": 1e-6, "T_dryer_out": 0.05,
                  "T_cyclone_out": 0.05}


@dataclass(frozen=True)
class WindowChoice:
    """One chosen calibration window and why.

    ``contributions`` holds each signal's std in the window relative to the record's;
    ``score`` is their sum; ``rank_of`` how many candidates were compared.
    """

    segment: Segment
    k0: int
    k1: int
    score: float
    contributions: dict[str, float]
    n_labs: int
    rank_of: int
    median_score: float
    whole_record: bool
    day: int = 0

    @property
    def reason(self) -> str:
        """One line for the output: which window and why."""
        span = f"{iso_utc(self.segment.start_ns)} .. {iso_utc(self.segment.end_ns)}"
        if self.whole_record:
            return (f"whole record {span} ({self.segment.hours:.1f} h, {self.n_labs} lab "
                    f"samples): not longer than the calibration window")
        top = sorted(self.contributions.items(), key=lambda kv: -kv[1])[:3]
        parts = ", ".join(f"{n} {v:.2f}x" for n, v in top)
        return (f"window {span} ({self.segment.hours:.1f} h, {self.n_labs} lab samples): "
                f"most natural variability of {self.rank_of} candidates, score "
                f"{self.score:.2f} (median {self.median_score:.2f}); largest: {parts} "
                f"their record-wide spread")


def _signal_matrix(seg: Segment) -> np.ndarray:
    """(K, n_signals) 600 s means of :data:`SCORED_SIGNALS`."""
    cols = [seg.U[:, INPUT_NAMES.index(n)] for n in MEASURED_INPUTS]
    cols += [seg.Y[:, OUTPUT_NAMES.index(n)] for n in SCANNED_OUTPUTS]
    return np.stack(cols, axis=1)


def variability_scores(seg: Segment, n_windows: int, step: int,
                       ref: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Scores of candidate windows starting at ``0, step, 2 step, ...``, each signal's spread
    in the window over ``ref`` (default: its spread over the segment).

    Returns ``(starts, contributions (n_candidates, n_signals))``; the score is the row sum.
    """
    X = _signal_matrix(seg)
    ref = np.nanstd(X, axis=0) if ref is None else ref
    floor = np.array([CONSTANT_BELOW[n] for n in SCORED_SIGNALS])
    varying = ref > floor
    starts = np.arange(0, seg.n_windows - n_windows + 1, step)
    contrib = np.zeros((len(starts), len(SCORED_SIGNALS)))
    for i, k in enumerate(starts):
        s = np.nanstd(X[k:k + n_windows], axis=0)
        contrib[i] = np.where(varying, np.nan_to_num(s) / np.where(varying, ref, 1.0), 0.0)
    return starts, contrib


def select_windows(seg: Segment, hours: float, count: int = 1, min_labs: int = 3,
                   min_hours: float = 2.0) -> list[WindowChoice]:
    """Pick ``count`` non-overlapping windows of ``hours`` with the most natural variability.

    A record not longer than ``hours`` is used whole. Raises :class:`IngestError` when the
    record is shorter than ``min_hours`` (or ``hours`` if less), has no lab sample at all, or
    no candidate window has ``min_labs`` lab samples.
    """
    n = int(round(hours * 3600.0 / seg.window))
    min_hours = min(min_hours, hours)
    if seg.hours < min_hours - 1e-9:
        raise IngestError(f"{seg.source}: {seg.hours:.2f} h of complete {seg.window:g} s windows "
                          f"is too short to calibrate (at least {min_hours:g} h)")
    seg.require_labs(1)
    if n >= seg.n_windows:
        return [WindowChoice(segment=seg, k0=0, k1=seg.n_windows, score=float("nan"),
                             contributions={}, n_labs=len(seg.lab_value), rank_of=1,
                             median_score=float("nan"), whole_record=True)]
    step = max(1, int(round(STEP_HOURS * 3600.0 / seg.window)))
    starts, contrib = variability_scores(seg, n, step)
    score = contrib.sum(axis=1)
    labs = np.array([seg.labs_before(k + n) - seg.labs_before(k) for k in starts])
    usable = labs >= min_labs
    if not usable.any():
        raise IngestError(f"{seg.source}: no {hours:g} h window holds {min_labs} lab samples "
                          f"(the record has {len(seg.lab_value)})")
    med = float(np.median(score[usable]))
    chosen: list[WindowChoice] = []
    taken = np.zeros(seg.n_windows, dtype=bool)
    order = np.argsort(-np.where(usable, score, -np.inf), kind="stable")
    for i in order:
        if len(chosen) >= count or not usable[i]:
            break
        k0, k1 = int(starts[i]), int(starts[i]) + n
        if taken[k0:k1].any():
            continue
        taken[k0:k1] = True
        chosen.append(WindowChoice(
            segment=seg.slice(k0, k1), k0=k0, k1=k1, score=float(score[i]),
            contributions=dict(zip(SCORED_SIGNALS, map(float, contrib[i]), strict=True)),
            n_labs=int(labs[i]), rank_of=int(usable.sum()), median_score=med,
            whole_record=False))
    if len(chosen) < count:
        raise IngestError(f"{seg.source}: only {len(chosen)} non-overlapping {hours:g} h "
                          f"window(s) with {min_labs} lab samples, {count} requested")
    return sorted(chosen, key=lambda c: c.k0)


def select_across(days: list[Segment], hours: float, budget_hours: float, min_labs: int = 3
                  ) -> list[WindowChoice]:
    """Windows of ``hours`` with the most natural variability *across* the history ``days``:
    every candidate of every day is scored against the signals' spread over all days (a
    production change counts by how rare it is in the history, not in its own day), and the
    best non-overlapping ones with ``min_labs`` lab samples are taken until ``budget_hours``
    are chosen (at least one). Days shorter than a window count as one candidate each.
    Raises :class:`IngestError` when no candidate holds ``min_labs`` lab samples."""
    ref = np.nanstd(np.vstack([_signal_matrix(d) for d in days]), axis=0)
    cands = []
    for i, seg in enumerate(days):
        n = min(int(round(hours * 3600.0 / seg.window)), seg.n_windows)
        step = max(1, int(round(STEP_HOURS * 3600.0 / seg.window)))
        starts, contrib = variability_scores(seg, n, step, ref)
        for k, c in zip(starts, contrib, strict=True):
            labs = seg.labs_before(int(k) + n) - seg.labs_before(int(k))
            if labs >= min_labs:
                cands.append((float(c.sum()), i, int(k), n, c, labs))
    if not cands:
        raise IngestError(f"no {hours:g} h window of the {len(days)} day(s) holds {min_labs} "
                          f"lab samples")
    med = float(np.median([c[0] for c in cands]))
    taken = [np.zeros(d.n_windows, dtype=bool) for d in days]
    chosen: list[WindowChoice] = []
    budget = max(budget_hours, hours)
    for score, i, k0, n, contrib, labs in sorted(cands, key=lambda c: -c[0]):
        if sum(c.segment.hours for c in chosen) + n * days[i].window / 3600.0 > budget + 1e-9:
            continue
        if taken[i][k0:k0 + n].any():
            continue
        taken[i][k0:k0 + n] = True
        seg = days[i]
        chosen.append(WindowChoice(
            segment=seg.slice(k0, k0 + n), k0=k0, k1=k0 + n, score=score,
            contributions=dict(zip(SCORED_SIGNALS, map(float, contrib), strict=True)),
            n_labs=int(labs), rank_of=len(cands), median_score=med,
            whole_record=n >= seg.n_windows, day=i))
    return sorted(chosen, key=lambda c: (c.day, c.k0))


def select_segments(days: Iterable[tuple[str, DayLike]], config: PlantConfig,
                    selection: DataSelection | None = None
                    ) -> tuple[list[Segment], list[WindowChoice]]:
    """Resample every ``(source, day)`` and pick its calibration window(s). ``days`` may be
    a generator (the apps read each file as it is needed, :mod:`softsensor.apps.loading`);
    ``selection`` defaults to :class:`DataSelection`'s."""
    selection = selection or DataSelection()
    segments, choices, n_days = [], [], 0
    for source, day in days:
        n_days += 1
        seg = segment_from_day(day, config, source=source)
        picked = select_windows(seg, selection.window_hours, selection.windows_per_day,
                                selection.min_labs)
        choices += picked
        segments += [c.segment for c in picked]
    if not n_days:
        raise IngestError("no recorded day given")
    return segments, choices


__all__ = ["SCORED_SIGNALS", "WindowChoice", "select_across", "select_segments",
           "select_windows", "variability_scores"]
