"""A recorded day as the model's windows, as diagnosis needs it.

The windows are those of the one windowing of the program
(:mod:`softsensor.windows.accumulator`): the estimator's and the calibration's
(:func:`softsensor.calibration.dataset.segment_from_windows`), so the diagnosis baseline on a
day is the calibration's prediction of that day and its eq. 4 cost is the one ``validate``
prints. :class:`DayWindows` holds

* the :class:`~softsensor.calibration.dataset.Segment`: per window the model inputs (held
  when missing, ``moisture_in`` at its nominal value as the calibrated open-loop model has
  it, or with a history's ``[model_error]`` at the history's typical inlet moisture), the
  measured window means of ``T_dryer_out`` and ``T_cyclone_out`` and the lab results with
  their sample-time alignment (:mod:`softsensor.windows.lab_alignment`);
* the :class:`~softsensor.messages.Window` objects themselves, which the inlet-moisture
  extension hands to the estimator exactly as the daemon does;
* ``air_edges``: ``T_air_in`` at every window boundary, from the sub-window bins on either
  side of it. The input-lag extension needs how ``T_air_in`` moved inside a window: the mean
  over a window of the inverse of a first-order lag ``x + tau dx/dt`` is exactly
  ``mean(x) + tau (x(end) - x(start)) / W``, which the edges give without differentiating
  noisy scans.

No ground truth is read: only ``scans`` and ``labs`` of the day.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softsensor.calibration.dataset import (
    DayLike,
    Segment,
    complete_windows,
    segment_from_windows,
    trim_stale,
)
from softsensor.calibration.model_error_fit import at_inlet_moisture
from softsensor.calibration.open_loop_errors import inlet_level
from softsensor.errors import IngestError
from softsensor.messages import Window
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS
from softsensor.windows.inputs import MEASURED_INPUTS

#: Fewest windows a day must have to be diagnosed (six hours of 600 s windows).
MIN_WINDOWS = 36
#: Spread of the model's outlet moisture at a lab's sample time about the plant's, beyond the
#: lab's own noise: on a 48 h virtual-plant day at the true parameters the sample-time
#: alignment leaves 0.0036 kg/kg RMS against a lab noise of 0.003, i.e.
#: ``sqrt(0.0036^2 - 0.003^2)`` (:mod:`softsensor.windows.lab_alignment`). [kg/kg]
MODEL_LAB_STD = 0.002

_T_AIR_BIN = MEASURED_INPUTS.index("T_air_in")
_T_AIR = INPUT_NAMES.index("T_air_in")


@dataclass(frozen=True)
class DayWindows:
    """A day as model windows (module docstring).

    Attributes
    ----------
    segment : Segment
        Inputs, measured temperatures, lab results and their alignment.
    windows : tuple of Window
        The same windows as the estimator receives them.
    air_edges : numpy.ndarray, shape (K + 1,)
        ``T_air_in`` at the window boundaries. [K]
    held : dict[str, int]
        Per measured input, how many windows held a previous value.
    """

    segment: Segment
    windows: tuple[Window, ...]
    air_edges: np.ndarray
    held: dict[str, int]

    @property
    def n_windows(self) -> int:
        return self.segment.n_windows

    @property
    def start_ns(self) -> int:
        """Start of the first window. [ns since the Unix epoch, UTC]"""
        return self.segment.start_ns

    @property
    def window_s(self) -> float:
        return self.segment.window

    @property
    def end_ns(self) -> np.ndarray:
        """Window end times (K,). [ns]"""
        return self.segment.window_ends_ns()

    @property
    def U(self) -> np.ndarray:
        """Model inputs (K, 8), :data:`~softsensor.signals.INPUT_NAMES` order (SI)."""
        return self.segment.U

    @property
    def Y(self) -> np.ndarray:
        """Measured window means of ``T_dryer_out`` and ``T_cyclone_out`` (K, 2), NaN where
        missing. [K]"""
        return self.segment.Y[:, :2]

    @property
    def lab_time_ns(self) -> np.ndarray:
        """Stamped lab sample times, sorted. [ns]"""
        return self.segment.lab_time_ns

    @property
    def lab_value(self) -> np.ndarray:
        """Lab ``moisture_out``. [kg/kg dry basis]"""
        return self.segment.lab_value

    @property
    def lab_id(self) -> tuple[str, ...]:
        return self.segment.lab_id

    @property
    def hours(self) -> np.ndarray:
        """Window end times in hours from the start. [h]"""
        return (self.end_ns - self.start_ns) / 3.6e12

    @property
    def lab_hours(self) -> np.ndarray:
        """Lab sample times in hours from the start. [h]"""
        return (self.lab_time_ns - self.start_ns) / 3.6e12

    @property
    def day_fraction(self) -> np.ndarray:
        """Each window's middle as a fraction of the day (to its last window's end). [-]"""
        return (self.hours - 0.5 * self.window_s / 3600.0) / float(self.hours[-1])

    @property
    def lab_window(self) -> np.ndarray:
        """The window of each lab sample: the first ending at or after it (``n_windows``
        for one after the last). [-]"""
        return np.searchsorted(self.end_ns, self.lab_time_ns, side="left")


def day_windows(day: DayLike, config: PlantConfig, source: str = "day") -> DayWindows:
    """Cut ``day`` into model windows (module docstring); ``source`` names it in errors.

    Raises :class:`~softsensor.errors.IngestError` when a scan signal is missing or has no
    good value, or the usable windows span less than ``MIN_WINDOWS`` windows.
    """
    scans = day.scans
    missing = [n for n in (*MEASURED_INPUTS, *KELVIN_CHANNELS) if n not in scans.columns]
    if missing:
        raise IngestError(f"{source}: signal {missing[0]} is missing from /plant/scan")
    windows = trim_stale(complete_windows(day, config, source), config, source)
    if len(windows) < MIN_WINDOWS:
        W = float(config.solver.window)
        raise IngestError(f"{source}: {len(windows) * W / 3600:.1f} h of usable windows; "
                          f"diagnosis needs at least {MIN_WINDOWS * W / 3600:g} h")
    seg = segment_from_windows(windows, day.labs, config, source)
    # the open-loop model's inlet moisture: with a history, its typical level, where the
    # plant's normal was taken
    seg = at_inlet_moisture(seg, inlet_level(config))
    held = {n: sum(1 for w in windows if w.means.get(n) is None) for n in MEASURED_INPUTS}
    return DayWindows(seg, tuple(windows), air_edges(seg), held)


def air_edges(seg: Segment) -> np.ndarray:
    """``T_air_in`` at the K + 1 window boundaries [K]: the mean of the good bins next to each
    boundary (the last of the window before, the first of the window after); where neither has
    a good value, the mean of the neighbouring windows' inputs."""
    K = seg.n_windows
    u = seg.U[:, _T_AIR]
    fallback = np.concatenate([[u[0]], 0.5 * (u[:-1] + u[1:]), [u[-1]]])
    if seg.bins.shape[1] == 0:
        return fallback
    first = seg.bins[:, 0, _T_AIR_BIN]
    last = seg.bins[:, -1, _T_AIR_BIN]
    left = np.concatenate([[np.nan], last])     # window before each boundary
    right = np.concatenate([first, [np.nan]])   # window after it
    pair = np.stack([left, right])
    n = np.isfinite(pair).sum(axis=0)
    with np.errstate(invalid="ignore"):
        mean = np.nansum(pair, axis=0) / np.maximum(n, 1)
    out = np.where(n > 0, mean, fallback)
    assert out.shape == (K + 1,)
    return out


def delagged_air(seg: Segment, edges: np.ndarray, tau_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Window inputs (K, 8) and sub-window bins with ``T_air_in`` de-lagged by a first-order
    time constant ``tau_s`` [s]: window means ``mean(x) + tau (x_end - x_start) / W``, bins
    ``x + tau dx/dt`` (what a lab sample saw) with the slope over one window either side of
    the bin. Not the slope between neighbouring bins: times a lag of 15 min, the sensor's
    0.5 K noise differenced over one bin put several kelvin of noise into the air at the lab
    times, and the fitted lag made the labs worse on the days it explained the temperatures
    best (8 of 12 independent-plant lag days missed, issue 39)."""
    U = seg.U.copy()
    U[:, _T_AIR] += tau_s * np.diff(edges) / seg.window
    bins = seg.bins.copy()
    if bins.shape[1]:
        K, n_bins, _ = bins.shape
        x = bins[:, :, _T_AIR_BIN].reshape(-1)
        t = np.arange(x.size, dtype=float)
        good = np.isfinite(x)
        if good.sum() >= 2:
            xf = np.interp(t, t[good], x[good])
            slope = (np.interp(t + n_bins, t, xf) - np.interp(t - n_bins, t, xf)) \
                / (2.0 * seg.window)
            bins[:, :, _T_AIR_BIN] = np.where(good, x + tau_s * slope, np.nan).reshape(K, n_bins)
    return U, bins


__all__ = ["MIN_WINDOWS", "MODEL_LAB_STD", "DayWindows", "air_edges", "day_windows",
           "delagged_air"]
