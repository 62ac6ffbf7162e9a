"""Calibration data: a recorded day as the model's windows, with its lab results aligned.

The paper (section 3.3) feeds the model "resampling 600 s" data. The windows are those of the
one windowing of the program (:mod:`softsensor.windows.accumulator`, the estimator's): aligned
to multiples of the window length since the Unix epoch, half-open ``(start, end]``, the mean of
the good scans of every signal, a signal with fewer good scans than ``solver.min_good_fraction``
of the expected ``window / scan period`` dropped (the scan period is ``solver.scan_period``
when set, else the day's own: the median spacing of its scans, so 1 s to 5 min historian
exports window alike). Every window's model inputs are its
input means, held when missing as the estimator holds them
(:class:`~softsensor.windows.inputs.InputHold`); its measured temperatures are its
means, missing where the window or the channel has too few good scans. Window means, not
end-of-window values, are compared with the model's end-of-window outputs: the plant's
controller moves ``T_air_in`` inside a window, and the model run on the window-mean inputs
matches the window-mean outputs several times better than the end-of-window samples (the fast
states sit at their quasi-steady profile; see :mod:`softsensor.model.kernels`).

Lab results are aligned to their *sample* time by :mod:`softsensor.windows.lab_alignment`
(the estimator's alignment too): the model is evaluated at the sample time, one step from the
start of its window with the inputs of the ``solver.lab_span`` seconds before it (``lab_U``).

``moisture_in`` is not measured; the open-loop model uses the config's ``nominal.moisture_in``.
Only complete windows inside the record are used: a window that starts before the first scan
or ends after the last is dropped. The day comes already read (reading MCAP files is the apps'
job, :mod:`softsensor.apps.loading`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.messages import Window, iso_utc
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS, OUTPUT_NAMES, TOPIC_LAB, TOPIC_SCAN
from softsensor.windows.accumulator import (
    NS,
    measured_scan_period,
    window_settings,
    windows_from_frame,
)
from softsensor.windows.inputs import MEASURED_INPUTS, InputHold
from softsensor.windows.lab_alignment import (
    bin_matrix,
    sample_inputs_from_bins,
    sample_offset,
    window_index,
)


class DayLike(Protocol):
    """A day of scans (index: log time [ns]) and lab results: a recorded
    :class:`~softsensor.recording.mcap_day.RecordedDay` or a simulated one."""

    scans: pd.DataFrame
    labs: pd.DataFrame


#: Output channels measured on every scan (the third, ``moisture_out``, comes from the lab).
SCANNED_OUTPUTS: tuple[str, ...] = KELVIN_CHANNELS


@dataclass(frozen=True)
class LabPoints:
    """Where lab samples meet the model (:mod:`softsensor.windows.lab_alignment`): the
    window holding each sample time, the seconds from its start, and the inputs there (L, 8)."""

    window: np.ndarray
    offset: np.ndarray
    inputs: np.ndarray


@dataclass(frozen=True)
class Segment:
    """A contiguous run of model windows with its measurements.

    Attributes
    ----------
    source : str
        Where the data came from (file path, possibly with the selected span).
    start_ns : int
        Start of the first window [ns since the Unix epoch, UTC].
    window : float
        Window length [s].
    U : ndarray, shape (K, 8)
        Model inputs per window in :data:`~softsensor.signals.INPUT_NAMES` order (SI).
    Y : ndarray, shape (K, 3)
        Measured outputs per window in :data:`~softsensor.signals.OUTPUT_NAMES` order: window
        means of ``T_dryer_out`` and ``T_cyclone_out`` [K] (NaN when too few good scans); the
        ``moisture_out`` column is NaN (it is measured by the lab, see ``lab_*``).
    lab_time_ns : ndarray, shape (L,)
        Lab sample times [ns], inside ``(start_ns, end_ns]``, sorted.
    lab_value : ndarray, shape (L,)
        Lab ``moisture_out`` [kg/kg dry basis].
    lab_id : tuple of str
        Lab sample ids.
    lab_U : ndarray, shape (L, 8), optional
        Model inputs at each sample time (:mod:`~softsensor.windows.lab_alignment`); by
        default the inputs of the sample's window.
    bins : ndarray, shape (K, n_bins, 7), optional
        Sub-window bin means of the measured inputs (NaN where a bin had no good value), as
        :attr:`softsensor.messages.Window.bins`; ``(K, 0, 7)`` when unknown.
    lab_span : float
        Seconds of scans before a sample time that give its inputs (``solver.lab_span``).
    T_sp : ndarray, shape (K,), optional
        Window means of the outlet loop's set point [K], held when missing (the operating
        point of :mod:`softsensor.estimation.model_error`); NaN when unknown.
    lab_window : ndarray of int, shape (L,)
        Window holding each sample time (derived).
    lab_offset : ndarray, shape (L,)
        Seconds from that window's start to the sample time, at least 1 (derived).
    """

    source: str
    start_ns: int
    window: float
    U: np.ndarray
    Y: np.ndarray
    lab_time_ns: np.ndarray
    lab_value: np.ndarray
    lab_id: tuple[str, ...]
    lab_U: np.ndarray | None = None
    bins: np.ndarray | None = None
    lab_span: float = 120.0
    T_sp: np.ndarray | None = None
    lab_window: np.ndarray = dataclasses.field(init=False, repr=False)
    lab_offset: np.ndarray = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        w_ns = self.window_ns
        win = np.clip(window_index(self.start_ns, w_ns, self.lab_time_ns), 0,
                      max(self.n_windows - 1, 0)).astype(np.int64)
        object.__setattr__(self, "lab_window", win)
        object.__setattr__(self, "lab_offset",
                           sample_offset(self.start_ns + win * w_ns, self.lab_time_ns))
        if self.lab_U is None:
            object.__setattr__(self, "lab_U", np.asarray(self.U)[win].reshape(-1, self.U.shape[1]))
        if self.bins is None:
            object.__setattr__(self, "bins", np.empty((self.n_windows, 0, len(MEASURED_INPUTS))))
        if self.T_sp is None:
            object.__setattr__(self, "T_sp", np.full(self.n_windows, np.nan))

    @property
    def n_windows(self) -> int:
        return int(self.U.shape[0])

    @property
    def window_ns(self) -> int:
        return int(round(self.window * NS))

    @property
    def end_ns(self) -> int:
        """End of the last window [ns]."""
        return self.start_ns + self.n_windows * self.window_ns

    @property
    def hours(self) -> float:
        return self.n_windows * self.window / 3600.0

    def window_ends_ns(self) -> np.ndarray:
        """End time of every window [ns]: the time of the model's output for that window."""
        return self.start_ns + self.window_ns * np.arange(1, self.n_windows + 1, dtype=np.int64)

    def default_lab_points(self) -> LabPoints:
        """The lab samples at their stamped times (the derived ``lab_*`` fields)."""
        return LabPoints(self.lab_window, self.lab_offset, self.lab_U)

    def lab_points(self, shift_ns: float = 0.0, U: np.ndarray | None = None,
                   bins: np.ndarray | None = None) -> LabPoints:
        """The lab samples with their sample times moved by ``shift_ns`` (a wrong stamp),
        aligned as a segment aligns them when it is made, inputs from ``bins`` and ``U`` (default
        the segment's own); sample times outside the segment clip to its ends."""
        U = self.U if U is None else np.asarray(U, float)
        bins = self.bins if bins is None else np.asarray(bins, float)
        w_ns = self.window_ns
        t = np.clip(np.round(self.lab_time_ns + shift_ns).astype(np.int64), self.start_ns + 1,
                    self.end_ns)
        win = np.clip(window_index(self.start_ns, w_ns, t), 0, self.n_windows - 1)
        starts = self.start_ns + win * w_ns
        n_bins = bins.shape[1]
        bin_ns = w_ns // n_bins if n_bins else 0
        span_ns = int(round(self.lab_span * NS))
        inputs = np.array([sample_inputs_from_bins(bins[k], int(s0), bin_ns, U[k], int(ti),
                                                   span_ns)
                           for k, s0, ti in zip(win, starts, t, strict=True)]
                          ).reshape(-1, U.shape[1])
        return LabPoints(win.astype(np.int64), sample_offset(starts, t), inputs)

    def labs_before(self, k: int) -> int:
        """Number of lab samples taken no later than the end of window ``k - 1``."""
        end = self.start_ns + k * self.window_ns
        return int(np.searchsorted(self.lab_time_ns, end, side="right"))

    def slice(self, k0: int, k1: int) -> Segment:
        """Windows ``k0 .. k1-1`` with the lab samples taken in them."""
        if not 0 <= k0 < k1 <= self.n_windows:
            raise ValueError(f"bad window slice [{k0}, {k1}) of {self.n_windows}")
        start = self.start_ns + k0 * self.window_ns
        end = self.start_ns + k1 * self.window_ns
        keep = (self.lab_time_ns > start) & (self.lab_time_ns <= end)
        return Segment(
            source=f"{self.source.split('[')[0]}[{iso_utc(start)} .. {iso_utc(end)}]",
            start_ns=start, window=self.window, U=self.U[k0:k1], Y=self.Y[k0:k1],
            lab_time_ns=self.lab_time_ns[keep], lab_value=self.lab_value[keep],
            lab_id=tuple(i for i, k in zip(self.lab_id, keep, strict=True) if k),
            lab_U=self.lab_U[keep], bins=self.bins[k0:k1], lab_span=self.lab_span,
            T_sp=self.T_sp[k0:k1])

    def require_labs(self, minimum: int = 1) -> None:
        """Refuse a segment without enough lab samples to fit ``moisture_out``."""
        if len(self.lab_value) < minimum:
            raise IngestError(
                f"{self.source}: {len(self.lab_value)} lab sample(s) ({TOPIC_LAB}) between "
                f"{iso_utc(self.start_ns)} and {iso_utc(self.end_ns)}; at least {minimum} "
                f"needed to calibrate moisture_out")


def trim_stale(windows: Sequence[Window], config: PlantConfig, source: str) -> list[Window]:
    """``windows`` without their leading and trailing stale windows (the model starts from a
    steady state at the first window's inputs, which must be measured). Raises
    :class:`IngestError` when none is usable, naming why."""
    usable = [i for i, w in enumerate(windows) if not w.stale]
    if not usable:
        reasons = windows[0].reasons if windows else {}
        why = "; ".join(f"{k}: {v}" for k, v in list(reasons.items())[:2]) or "no scans"
        raise IngestError(
            f"{source}: no {config.solver.window:g} s window has enough good scans of every "
            f"model input (first window: {why})")
    return list(windows[usable[0]:usable[-1] + 1])


def segment_from_windows(windows: Sequence[Window], labs: pd.DataFrame, config: PlantConfig,
                         source: str) -> Segment:
    """Windows of :mod:`~softsensor.windows.accumulator` (consecutive, in time order) and the
    lab results (``sample_time_ns``, ``moisture_out``, ``sample_id``) as a :class:`Segment`.

    Leading and trailing stale windows are dropped (the model starts from a steady state at the
    first window's inputs, which must be measured). Raises :class:`IngestError` when no window
    is usable, naming why.
    """
    settings = window_settings(config)
    kept = trim_stale(windows, config, source)
    hold = InputHold(config.nominal_inputs())
    U = np.empty((len(kept), len(INPUT_NAMES)))
    Y = np.full((len(kept), len(OUTPUT_NAMES)), np.nan)
    T_sp = np.full(len(kept), float(config.nominal.T_sp))
    for k, w in enumerate(kept):
        U[k], _ = hold.inputs(w)
        sp = w.means.get("T_sp")
        T_sp[k] = sp if sp is not None and math.isfinite(sp) else T_sp[k - 1] if k else T_sp[k]
        if not w.stale:
            for c, name in enumerate(SCANNED_OUTPUTS):
                v = w.means.get(name)
                if v is not None and math.isfinite(v):
                    Y[k, c] = v
    U[:, INPUT_NAMES.index("moisture_in")] = config.nominal.moisture_in
    bins = np.stack([bin_matrix(w) for w in kept])
    start = int(kept[0].start_ns)
    w_ns = settings.period_ns
    end = start + len(kept) * w_ns
    lt = labs["sample_time_ns"].to_numpy(dtype=np.int64)
    lv = labs["moisture_out"].to_numpy(dtype=float)
    keep = (lt > start) & (lt <= end) & np.isfinite(lv)
    order = np.argsort(lt[keep], kind="stable")
    ids = np.asarray(labs["sample_id"].to_numpy(dtype=object))[keep][order]
    lab_t = lt[keep][order]
    k_lab = window_index(start, w_ns, lab_t)
    span_ns = int(round(config.solver.lab_span * NS))
    lab_U = np.array([sample_inputs_from_bins(bins[k], start + k * w_ns, settings.bin_ns, U[k],
                                              int(t), span_ns)
                      for k, t in zip(k_lab, lab_t, strict=True)]).reshape(-1, U.shape[1])
    return Segment(source=source, start_ns=start, window=settings.period_s, U=U, Y=Y,
                   lab_time_ns=lab_t, lab_value=lv[keep][order],
                   lab_id=tuple(str(i) for i in ids), lab_U=lab_U, bins=bins,
                   lab_span=config.solver.lab_span, T_sp=T_sp)


def segment_from_day(day: DayLike, config: PlantConfig, *, source: str | None = None
                     ) -> Segment:
    """A recorded day as model windows (module docstring for the rules).

    Parameters
    ----------
    day : RecordedDay or SimulatedDay
        Scans and lab results (the ground-truth topic, if any, is never read).
    config : PlantConfig
        Windowing (``[solver]``) and ``nominal.moisture_in`` [kg/kg].

    Raises
    ------
    IngestError
        No scans, no complete window, an input or temperature signal without any good value,
        or no usable window.
    """
    src = source or str(day.path)
    return segment_from_windows(complete_windows(day, config, src), day.labs, config, src)


def complete_windows(day: DayLike, config: PlantConfig, source: str) -> list[Window]:
    """The day's scans as the windows of :mod:`softsensor.windows.accumulator` that lie
    wholly inside the record. Raises :class:`IngestError` for no scans, a signal without any
    good value, or no complete window."""
    scans = day.scans
    if len(scans) == 0:
        raise IngestError(f"{source}: no scans ({TOPIC_SCAN}) in the recording")
    for name in MEASURED_INPUTS + SCANNED_OUTPUTS:
        if name not in scans.columns or not np.isfinite(scans[name].to_numpy(float)).any():
            raise IngestError(f"{source}: signal {name} has no good value in {TOPIC_SCAN}")
    t = scans.index.to_numpy(dtype=np.int64)
    settings = window_settings(config, measured_scan_period(t))
    first, last = int(t.min()), int(t.max())
    windows = [w for w in windows_from_frame(scans.sort_index(), settings)
               if w.start_ns >= first and w.end_ns <= last]
    if not windows:
        raise IngestError(f"{source}: {(last - first) / NS / 3600:.2f} h of scans holds no "
                          f"complete {settings.period_s:g} s window")
    return windows


__all__ = [
    "MEASURED_INPUTS",
    "SCANNED_OUTPUTS",
    "DayLike",
    "LabPoints",
    "Segment",
    "complete_windows",
    "segment_from_day",
    "segment_from_windows",
    "trim_stale",
]
