"""Scans to estimator windows: a pure, deterministic accumulator.

Windows are ``period_s`` long (600 s by default) and aligned to multiples of the period since
the Unix epoch; a window is the half-open interval ``(start, end]``, so a scan stamped exactly
on a boundary belongs to the window that ends there. For each window the accumulator averages
the good values (non-null, finite) of every signal of :data:`~softsensor.signals.SCAN_SIGNALS`.

Every value is judged before it is summed (:mod:`softsensor.windows.plausibility`): one
outside its plausible range, or a jump no sensor makes, is refused and counted in
``Window.refused`` with the reason in ``Window.reasons``; a value beyond
:data:`~softsensor.windows.plausibility.MAX_MAGNITUDE` is refused even without limits, so
a window's sum can never overflow and no accumulator can hold something a checkpoint could
not restore.

A signal with fewer good values than ``min_fraction`` of the expected scans
(``period_s / scan_period_s``, 60 for 10 s scans; 50 % -> 30) gets the mean ``None`` and a reason.
The window is ``stale`` when fewer scans than that arrived, or when a signal of ``required``
(by default the measured model inputs) is ``None``; ``Window.reasons`` then also says why under
the key ``"scans"`` or the signal's name. Windows without any scan (a gap in the data) are
emitted too, stale, so time keeps advancing for the estimator.

Each window also keeps, per measured model input, the mean of its good values in consecutive
bins of ``bin_s`` seconds (60 s): what a lab sample taken inside the window saw
(:mod:`softsensor.windows.lab_alignment`). This accumulator is the one windowing of the
program: the estimator service feeds it live, calibration and diagnosis feed it a recorded day
(:func:`windows_from_frame`), so all three see the same windows.

No I/O and no clock: time is whatever the scans (or :meth:`WindowAccumulator.advance`) say.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from softsensor.errors import ConfigError
from softsensor.messages import Window, scan_values
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS
from softsensor.windows.plausibility import InputJudge, Plausibility, plausibility_from_config

NS = 10**9
#: Signals without which a window cannot drive the model: the measured inputs.
MODEL_SIGNALS: tuple[str, ...] = tuple(n for n in INPUT_NAMES if n in SCAN_SIGNALS)
#: Default length of the sub-window bins of the measured inputs [s].
BIN_S = 60.0
#: Scan period assumed when neither the config nor the data give one [s] (CONTRACT section 1).
NOMINAL_SCAN_PERIOD_S = 10.0


@dataclass(frozen=True)
class WindowSettings:
    """How scans are grouped and judged.

    Attributes
    ----------
    period_s : float
        Window length [s]; windows end on multiples of it since the epoch.
    scan_period_s : float
        Nominal scan period [s].
    min_fraction : float
        Fraction of the expected scans (``period_s / scan_period_s``) below which a signal is
        dropped and the window is stale. [-]
    required : tuple of str
        Signals whose absence makes the window stale.
    bin_s : float
        Length of the sub-window bins of the measured inputs [s]; must divide ``period_s``.
    plausibility : Plausibility, optional
        Per-signal range and rate limits judged before a value is summed; None: only
        :data:`~softsensor.windows.plausibility.MAX_MAGNITUDE`.
    """

    period_s: float = 600.0
    scan_period_s: float = 10.0
    min_fraction: float = 0.5
    required: tuple[str, ...] = MODEL_SIGNALS
    bin_s: float = BIN_S
    plausibility: Plausibility | None = None

    def __post_init__(self) -> None:
        if not (self.period_s > 0 and math.isfinite(self.period_s)):
            raise ConfigError(f"window.period_s must be > 0, got {self.period_s}")
        if (self.period_s * NS) % 1:
            raise ConfigError(f"window.period_s must be a whole number of ns, got {self.period_s}")
        if not 0 < self.scan_period_s <= self.period_s:
            raise ConfigError(f"window.scan_period_s must be in (0, period_s], "
                              f"got {self.scan_period_s}")
        if not 0 <= self.min_fraction <= 1:
            raise ConfigError(f"window.min_fraction must be in 0..1, got {self.min_fraction}")
        unknown = [s for s in self.required if s not in SCAN_SIGNALS]
        if unknown:
            raise ConfigError(f"window.required names unknown signal {unknown[0]!r}")
        if not (0 < self.bin_s <= self.period_s) or (self.period_ns % self.bin_ns):
            raise ConfigError(f"window.bin_s must divide the window ({self.period_s:g} s), "
                              f"got {self.bin_s}")

    @property
    def period_ns(self) -> int:
        """Window length [ns]."""
        return int(round(self.period_s * NS))

    @property
    def bin_ns(self) -> int:
        """Bin length [ns]."""
        return int(round(self.bin_s * NS))

    @property
    def n_bins(self) -> int:
        """Bins per window."""
        return self.period_ns // self.bin_ns

    @property
    def expected_scans(self) -> int:
        """Scans expected in a full window."""
        return max(1, int(round(self.period_s / self.scan_period_s)))

    @property
    def min_good(self) -> int:
        """Fewest good values (and scans) a usable window needs."""
        return math.ceil(self.min_fraction * self.expected_scans - 1e-9)


def measured_scan_period(times_ns: Iterable[int]) -> float | None:
    """The scan period [s] of a record: the median spacing of its distinct scan times.

    The median, not the mean, so that gaps (a stopped historian, a PLC outage) and the odd
    duplicated or jittered timestamp do not move it. None for fewer than two distinct times.
    """
    t = sorted(set(int(x) for x in times_ns))
    if len(t) < 2:
        return None
    steps = sorted(b - a for a, b in zip(t[:-1], t[1:], strict=True))
    return steps[len(steps) // 2] / NS


def window_settings(config: PlantConfig, measured_s: float | None = None,
                    **overrides: Any) -> WindowSettings:
    """The windowing of ``config`` (``[solver]``: window, scan period, good share).

    The scan period is ``solver.scan_period`` when the config sets it, else ``measured_s``
    (the data's own period, :func:`measured_scan_period`), else
    :data:`NOMINAL_SCAN_PERIOD_S`; never longer than the window. Values are judged by the
    config's ``[plausibility]`` limits (every path that windows scans judges them alike).
    """
    s = config.solver
    period = s.scan_period if s.scan_period is not None else measured_s
    period = NOMINAL_SCAN_PERIOD_S if period is None else min(float(period), s.window)
    kwargs: dict[str, Any] = {"period_s": s.window, "scan_period_s": period,
                              "min_fraction": s.min_good_fraction,
                              "plausibility": plausibility_from_config(config)}
    kwargs.update(overrides)
    return WindowSettings(**kwargs)


def window_end(time_ns: int, period_ns: int) -> int:
    """End [ns] of the aligned window ``(end - period, end]`` holding ``time_ns``."""
    return -((-time_ns) // period_ns) * period_ns


class _Sums:
    __slots__ = ("bin_n", "bin_sum", "n_scans", "refused", "values", "why")

    def __init__(self, n_bins: int) -> None:
        self.n_scans = 0
        self.values: dict[str, list[float]] = {name: [] for name in SCAN_SIGNALS}
        self.bin_sum = {name: [0.0] * n_bins for name in MODEL_SIGNALS}
        self.bin_n = {name: [0] * n_bins for name in MODEL_SIGNALS}
        self.refused: dict[str, int] = {}
        self.why: dict[str, str] = {}  # the first reason a signal's value was refused


class WindowAccumulator:
    """Turns a stream of scans into :class:`~softsensor.messages.Window` objects.

    Parameters
    ----------
    settings : WindowSettings
        Window length, expected scans, thresholds.
    start_ns : int, optional
        Emit windows from the one holding ``start_ns + 1`` on (gap windows before the first
        scan included); by default the first window is the first scan's.

    judge_state : dict, optional
        :meth:`InputJudge.state` as it was at the start of the window being filled (from
        :attr:`judge_state_at_window_start` of a checkpointed accumulator): its scans, fed
        again, are judged as they were.
    max_gap_windows : int, optional
        Longest run of empty (gap) windows emitted at once: of a longer gap only the last
        ``max_gap_windows`` are emitted, the others are counted in ``n_skipped`` and the gap's
        start is kept in ``stale_since_ns``. The live service bounds gaps so that one scan
        stamped years ahead costs a fixed amount of work; recorded days for calibration keep
        every window (None, the default).

    Feed scans with :meth:`add` (each call returns the windows it completed), let time pass
    without scans with :meth:`advance`, and end with :meth:`flush`. Scans for a window already
    emitted are counted in ``n_late`` and dropped.
    """

    def __init__(self, settings: WindowSettings | None = None, *,
                 start_ns: int | None = None, max_gap_windows: int | None = None,
                 judge_state: Mapping[str, Any] | None = None) -> None:
        self.settings = settings or WindowSettings()
        self.judge = InputJudge(self.settings.plausibility or Plausibility(limits={}))
        if judge_state is not None:
            self.judge.restore(judge_state)
        #: the judge's memory when the window being filled began (what a checkpoint keeps)
        self.judge_state_at_window_start = self.judge.state()
        self._period = self.settings.period_ns
        self._end: int | None = None  # end of the window being filled
        self._sums = _Sums(self.settings.n_bins)
        self._emitted_end: int | None = None  # end of the last emitted window
        if start_ns is not None:
            self._end = window_end(start_ns + 1, self._period)
        if max_gap_windows is not None and max_gap_windows < 1:
            raise ConfigError(f"max_gap_windows must be >= 1, got {max_gap_windows}")
        self.max_gap_windows = max_gap_windows
        self.n_late = 0
        self.n_skipped = 0  #: gap windows not emitted (longer than ``max_gap_windows``)
        self.stale_since_ns: int | None = None  #: start of the last gap that was cut short

    @property
    def current_end_ns(self) -> int | None:
        """End [ns] of the window being filled (None before the first scan)."""
        return self._end

    def add(self, time_ns: int, body: Mapping[str, Any]) -> list[Window]:
        """Add one scan (a ``/plant/scan`` body, SI units); return the windows it completed.

        Raises :class:`~softsensor.errors.IngestError` for an unknown signal in ``body``.
        """
        t = int(time_ns)
        values = scan_values(dict(body), where=f"scan at {t} ns")
        end = window_end(t, self._period)
        if self._emitted_end is not None and end <= self._emitted_end:
            self.n_late += 1
            return []
        out: list[Window] = []
        if self._end is None:
            self._end = end
        elif end > self._end:
            out = self._close_until(end - self._period)
            self._end = end
        elif end < self._end:  # before a start_ns given explicitly
            self.n_late += 1
            return []
        sums = self._sums
        sums.n_scans += 1
        b = min(max((t - (self._end - self._period) - 1) // self.settings.bin_ns, 0),
                self.settings.n_bins - 1)
        for name, v in values.items():
            if not math.isfinite(v):
                continue
            why = self.judge.judge(name, t, v)
            if why is not None:  # judged before it is summed: never part of a mean
                sums.refused[name] = sums.refused.get(name, 0) + 1
                sums.why.setdefault(name, why)
                continue
            sums.values[name].append(v)
            if name in sums.bin_sum:
                sums.bin_sum[name][b] += v
                sums.bin_n[name][b] += 1
        return out

    def advance(self, now_ns: int) -> list[Window]:
        """Emit every window that ends at or before ``now_ns`` (stale ones for gaps)."""
        if self._end is None:
            return []
        if now_ns < self._end:
            return []
        last_end = window_end(int(now_ns), self._period)
        if last_end > now_ns:
            last_end -= self._period
        out = self._close_until(last_end)
        self._end = last_end + self._period
        return out

    def flush(self) -> list[Window]:
        """Emit the window being filled, if it has any scan (end of a recorded day)."""
        if self._end is None or self._sums.n_scans == 0:
            return []
        return self._close_until(self._end)

    def _close_until(self, last_end: int) -> list[Window]:
        """Close the current window and emit gap windows up to the one ending at ``last_end``."""
        assert self._end is not None
        n_bins = self.settings.n_bins
        out = [self._build(self._end - self._period, self._end, self._sums)]
        self._sums = _Sums(n_bins)
        end = self._end + self._period
        n_gap = (last_end - self._end) // self._period
        if self.max_gap_windows is not None and n_gap > self.max_gap_windows:
            # a gap longer than the bound: one "stale since" state, then the last windows
            skip = n_gap - self.max_gap_windows
            self.n_skipped += skip
            self.stale_since_ns = self._end
            end += skip * self._period
        while end <= last_end:
            out.append(self._build(end - self._period, end, _Sums(n_bins)))
            end += self._period
        self._emitted_end = last_end if last_end >= self._end else self._end
        self._end = end
        self.judge_state_at_window_start = self.judge.state()
        return out

    def _build(self, start: int, end: int, sums: _Sums) -> Window:
        s = self.settings
        expected, min_good = s.expected_scans, s.min_good
        means: dict[str, float | None] = {}
        n_good: dict[str, int] = {}
        reasons: dict[str, str] = {}
        for name in SCAN_SIGNALS:
            vals = sums.values[name]
            n_good[name] = len(vals)
            if vals and len(vals) >= min_good:
                means[name] = math.fsum(vals) / len(vals)  # every value judged: no overflow
            else:
                means[name] = None
                reasons[name] = (f"{len(vals)} good values in {sums.n_scans} scans, "
                                 f"{min_good} of {expected} expected needed")
            if name in sums.refused:
                refused = (f"{sums.refused[name]} implausible values refused (first: "
                           f"{sums.why[name]})")
                reasons[name] = f"{reasons[name]}; {refused}" if name in reasons else refused
        stale = False
        if sums.n_scans < min_good:
            stale = True
            reasons["scans"] = ("no scans (gap in the data)" if sums.n_scans == 0 else
                                f"{sums.n_scans} scans, {min_good} of {expected} expected needed")
        missing = [name for name in s.required if means[name] is None]
        if missing:
            stale = True
        bins = {name: [sums.bin_sum[name][b] / n if n else None
                       for b, n in enumerate(sums.bin_n[name])] for name in MODEL_SIGNALS}
        return Window(start_ns=start, end_ns=end, means=means, n_scans=sums.n_scans,
                      n_good=n_good, stale=stale, reasons=reasons, bin_s=s.bin_s, bins=bins,
                      refused=dict(sums.refused))


def windows_from_scans(scans: Iterable[tuple[int, Mapping[str, Any]]],
                       settings: WindowSettings | None = None, *,
                       start_ns: int | None = None, end_ns: int | None = None) -> list[Window]:
    """All windows of a sequence of ``(time_ns, body)`` scans in time order.

    The last, partly filled window is included; with ``end_ns`` the windows run up to the one
    holding ``end_ns`` (stale gap windows included).
    """
    acc = WindowAccumulator(settings, start_ns=start_ns)
    out: list[Window] = []
    for t, body in scans:
        out.extend(acc.add(t, body))
    if end_ns is not None and acc.current_end_ns is not None:
        out.extend(acc.advance(window_end(end_ns, acc.settings.period_ns)))
    else:
        out.extend(acc.flush())
    return out


def windows_from_frame(scans: Any, settings: WindowSettings | None = None, **kwargs: Any,
                       ) -> list[Window]:
    """:func:`windows_from_scans` over a ``RecordedDay.scans`` DataFrame (index = ns)."""
    columns = [c for c in scans.columns if c in SCAN_SIGNALS]
    rows = ((int(t), dict(zip(columns, vals, strict=True)))
            for t, vals in zip(scans.index, scans[columns].itertuples(index=False, name=None),
                               strict=True))
    return windows_from_scans(rows, settings, **kwargs)


__all__ = [
    "BIN_S",
    "MODEL_SIGNALS",
    "WindowAccumulator",
    "WindowSettings",
    "window_end",
    "windows_from_frame",
    "windows_from_scans",
    "window_settings",
]
