"""Calibration data: a recorded day resampled to the model's 600 s windows.

The paper (section 3.3) feeds the model "resampling 600 s" data: every window's inputs are the
mean of the good scans in it, held constant over the window (the model's piecewise-constant
inputs), and every window's measured temperatures are the mean of its good scans. Window means
and not end-of-window values are compared with the model's end-of-window outputs: the plant's
controller moves ``T_air_in`` inside a window, and the model run on the window-mean inputs
matches the window-mean outputs several times better than the end-of-window samples (the fast
states sit at their quasi-steady profile; see :mod:`softsensor.model.kernels`).

Lab results are aligned to their *sample* time, not to the time the result was logged. The
fibre in a lab sample left the cyclone at that instant, a few seconds after it entered the
tube; the fast states follow the inputs within seconds, so the model is evaluated *at the
sample time*: the wall state at the start of the sample's window, stepped to the sample time,
with the inputs averaged over the :data:`LAB_SPAN` seconds of scans before it (``lab_U``).
The closed loop moves ``T_air_in`` within a window (about 0.7 K r.m.s. on the virtual
plant), so this halves the model-to-lab error compared with interpolating window-mean
outputs (0.0036 against 0.0064 kg/kg at the true parameters of a 48 h virtual-plant day,
lab noise 0.003).

``moisture_in`` is not measured; the open-loop model uses the config's ``nominal.moisture_in``.

Windows are aligned to multiples of the window length since the Unix epoch and are half-open
``(start, end]``, as the estimator service's :class:`~softsensor.estimation.base.Window`.
Only complete windows inside the record are used.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.estimation.window_inputs import MEASURED_INPUTS
from softsensor.estimation.windowing import NS
from softsensor.plantconfig import PlantConfig
from softsensor.recording.mcap_day import RecordedDay, read_day
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS, OUTPUT_NAMES, TOPIC_LAB, TOPIC_SCAN

#: Output channels measured on every scan (the third, ``moisture_out``, comes from the lab).
SCANNED_OUTPUTS: tuple[str, ...] = KELVIN_CHANNELS
#: A window's mean is used only when at least this share of its nominal scans is good.
MIN_GOOD_SHARE = 0.5
#: Nominal PLC scan period [s] (CONTRACT section 1).
SCAN_PERIOD = 10.0
#: Scans before a lab sample time averaged into its inputs [s].
LAB_SPAN = 120.0
#: Good scans of a signal needed in that span; fewer: the window mean is used.
LAB_MIN_SCANS = 3


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
        Model inputs at each sample time (scans of the last :data:`LAB_SPAN` s); by default
        the inputs of the sample's window.
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
    lab_window: np.ndarray = dataclasses.field(init=False, repr=False)
    lab_offset: np.ndarray = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        w_ns = self.window_ns
        rel = np.asarray(self.lab_time_ns, dtype=np.int64) - self.start_ns
        win = np.clip((rel - 1) // w_ns, 0, max(self.n_windows - 1, 0)).astype(np.int64)
        object.__setattr__(self, "lab_window", win)
        object.__setattr__(self, "lab_offset", np.maximum((rel - win * w_ns) / NS, 1.0))
        if self.lab_U is None:
            object.__setattr__(self, "lab_U", np.asarray(self.U)[win].reshape(-1, self.U.shape[1]))

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
            source=f"{self.source.split('[')[0]}[{_iso(start)} .. {_iso(end)}]",
            start_ns=start, window=self.window, U=self.U[k0:k1], Y=self.Y[k0:k1],
            lab_time_ns=self.lab_time_ns[keep], lab_value=self.lab_value[keep],
            lab_id=tuple(i for i, k in zip(self.lab_id, keep, strict=True) if k),
            lab_U=self.lab_U[keep])

    def require_labs(self, minimum: int = 1) -> None:
        """Refuse a segment without enough lab samples to fit ``moisture_out``."""
        if len(self.lab_value) < minimum:
            raise IngestError(
                f"{self.source}: {len(self.lab_value)} lab sample(s) ({TOPIC_LAB}) between "
                f"{_iso(self.start_ns)} and {_iso(self.end_ns)}; at least {minimum} needed to "
                f"calibrate moisture_out")


def _iso(t_ns: int) -> str:
    return pd.Timestamp(int(t_ns), unit="ns", tz="UTC").strftime("%Y-%m-%dT%H:%MZ")


def window_means(scans: pd.DataFrame, start_ns: int, window_ns: int, n_windows: int,
                 columns: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Means and good-value counts of ``columns`` per window ``(start + k w, start + (k+1) w]``.

    Returns ``(means (K, C), counts (K, C))``; a window without good values has a NaN mean.
    """
    t = scans.index.to_numpy(dtype=np.int64)
    k = (t - start_ns - 1) // window_ns
    inside = (k >= 0) & (k < n_windows)
    k = k[inside]
    means = np.full((n_windows, len(columns)), np.nan)
    counts = np.zeros((n_windows, len(columns)), dtype=np.int64)
    for j, name in enumerate(columns):
        v = scans[name].to_numpy(dtype=float)[inside]
        good = np.isfinite(v)
        counts[:, j] = np.bincount(k[good], minlength=n_windows)
        sums = np.bincount(k[good], weights=v[good], minlength=n_windows)
        with np.errstate(invalid="ignore", divide="ignore"):
            means[:, j] = np.where(counts[:, j] > 0, sums / np.maximum(counts[:, j], 1), np.nan)
    return means, counts


def lab_inputs(scans: pd.DataFrame, lab_time_ns: np.ndarray, U: np.ndarray, start_ns: int,
               window_ns: int, span: float = LAB_SPAN) -> np.ndarray:
    """Model inputs at each lab sample time: means of the scans in ``(t - span, t]``; a
    signal with fewer than :data:`LAB_MIN_SCANS` good scans there takes its window mean."""
    t = scans.index.to_numpy(dtype=np.int64)
    vals = scans[list(MEASURED_INPUTS)].to_numpy(dtype=float)
    out = np.empty((len(lab_time_ns), U.shape[1]))
    for i, ts in enumerate(lab_time_ns):
        k = int(np.clip((ts - start_ns - 1) // window_ns, 0, len(U) - 1))
        out[i] = U[k]
        lo, hi = np.searchsorted(t, [ts - int(span * NS), ts], side="right")
        block = vals[lo:hi]
        good = np.isfinite(block)
        n = good.sum(axis=0)
        with np.errstate(invalid="ignore"):
            mean = np.where(good, block, 0.0).sum(axis=0) / np.maximum(n, 1)
        use = n >= LAB_MIN_SCANS
        out[i, :len(MEASURED_INPUTS)][use] = mean[use]
    return out


def _hold(values: np.ndarray) -> np.ndarray:
    """Fill NaN windows with the last good value (the first good one before it starts)."""
    out = pd.DataFrame(values).ffill().bfill().to_numpy()
    return out


def segment_from_day(day: RecordedDay, config: PlantConfig, *, window: float | None = None,
                     source: str | None = None) -> Segment:
    """Resample a recorded day to model windows (module docstring for the rules).

    Parameters
    ----------
    day : RecordedDay
        Scans and lab results (the ground-truth topic, if any, is never read).
    config : PlantConfig
        Gives the window length (``solver.window``) and ``nominal.moisture_in`` [kg/kg].
    window : float, optional
        Window length [s]; default ``config.solver.window`` (600 s).

    Raises
    ------
    IngestError
        No scans, a day shorter than one window, or an input or temperature signal without
        any good value.
    """
    src = source or str(day.path)
    window = float(config.solver.window if window is None else window)
    w_ns = int(round(window * NS))
    scans = day.scans
    if len(scans) == 0:
        raise IngestError(f"{src}: no scans ({TOPIC_SCAN}) in the recording")
    first, last = int(scans.index[0]), int(scans.index[-1])
    start = -(-first // w_ns) * w_ns  # first window boundary at or after the first scan
    n = (last - start) // w_ns
    if n < 1:
        raise IngestError(f"{src}: {(last - first) / NS / 3600:.2f} h of scans holds no complete "
                          f"{window:g} s window")
    for name in MEASURED_INPUTS + SCANNED_OUTPUTS:
        if name not in scans.columns or not np.isfinite(scans[name].to_numpy(float)).any():
            raise IngestError(f"{src}: signal {name} has no good value in {TOPIC_SCAN}")
    min_count = max(1, math.ceil(MIN_GOOD_SHARE * window / SCAN_PERIOD))
    u_mean, u_count = window_means(scans, start, w_ns, n, MEASURED_INPUTS)
    u_mean[u_count < min_count] = np.nan
    if np.isnan(u_mean).all(axis=0).any():
        bad = MEASURED_INPUTS[int(np.flatnonzero(np.isnan(u_mean).all(axis=0))[0])]
        raise IngestError(f"{src}: signal {bad} has no window with {min_count} good scans")
    U = np.empty((n, len(INPUT_NAMES)))
    U[:, :len(MEASURED_INPUTS)] = _hold(u_mean)
    U[:, INPUT_NAMES.index("moisture_in")] = config.nominal.moisture_in
    y_mean, y_count = window_means(scans, start, w_ns, n, SCANNED_OUTPUTS)
    y_mean[y_count < min_count] = np.nan
    Y = np.full((n, len(OUTPUT_NAMES)), np.nan)
    Y[:, :2] = y_mean
    labs = day.labs
    lt = labs["sample_time_ns"].to_numpy(dtype=np.int64)
    lv = labs["moisture_out"].to_numpy(dtype=float)
    keep = (lt > start) & (lt <= start + n * w_ns) & np.isfinite(lv)
    order = np.argsort(lt[keep], kind="stable")
    ids = np.asarray(labs["sample_id"].to_numpy(dtype=object))[keep][order]
    lab_t = lt[keep][order]
    return Segment(source=src, start_ns=start, window=window, U=U, Y=Y, lab_time_ns=lab_t,
                   lab_value=lv[keep][order], lab_id=tuple(str(i) for i in ids),
                   lab_U=lab_inputs(scans, lab_t, U, start, w_ns))


def load_segment(path: str | Path, config: PlantConfig) -> Segment:
    """Read a recorded day (scans and lab topics only) and resample it to model windows."""
    day = read_day(path, topics=[TOPIC_SCAN, TOPIC_LAB])
    return segment_from_day(day, config, source=str(path))


__all__ = [
    "MEASURED_INPUTS",
    "SCANNED_OUTPUTS",
    "Segment",
    "lab_inputs",
    "load_segment",
    "segment_from_day",
    "window_means",
]
