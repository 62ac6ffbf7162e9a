"""A recorded day cut into the model's 600 s windows, as diagnosis needs it.

Each window ``k`` covers the log times ``(t0 + k W, t0 + (k + 1) W]`` with ``t0`` the first scan
and ``W`` the config's ``solver.window``. The model inputs of a window are the means of the good
scans of the seven measured inputs (a window without a good value of an input holds the last
window's value, before any good value the config's nominal value); ``moisture_in`` is not
measured and takes the nominal value, as the calibrated open-loop model does. The measured
outputs are the window means of ``T_dryer_out`` and ``T_cyclone_out`` (NaN without a good scan)
and are compared with the model's outputs at the window's end: the tube and cyclone profiles
are quasi-steady at this time scale (``shared/MODEL.md``, "Time scales"), so on a clean
virtual-plant day with the true parameters the two differ by the scan noise of a window mean
(about 0.5 K / sqrt(60) = 0.065 K) plus 0.03 K of model discretisation.

Lab results are kept with their stamped sample time; :func:`lab_model_values` interpolates the
model's outlet moisture at a sample time, each window's output standing at the window's centre.

Besides window means the input-lag extension needs how ``T_air_in`` moved inside a window:
``air_edges`` holds ``T_air_in`` at every window boundary, the mean of the scans within
``EDGE_HALF_WIDTH`` of it. The mean over a window of the inverse of a first-order lag
``x + tau dx/dt`` is exactly ``mean(x) + tau (x(end) - x(start)) / W``, which these edges give
without differentiating noisy scans.

No ground truth is read: only ``scans`` and ``labs`` of the day.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.plantconfig import PlantConfig
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS

#: Half width of the scan average that estimates ``T_air_in`` at a window boundary. [s]
EDGE_HALF_WIDTH = 60.0
#: A trailing window shorter than this fraction of ``W`` is dropped.
MIN_LAST_FRACTION = 0.5
#: Fewest windows a day must have to be diagnosed (six hours).
MIN_WINDOWS = 36
#: Spread of the instantaneous outlet moisture a lab samples about its window mean, which a
#: window-mean model cannot follow (virtual plant, clean days, true parameters). [kg/kg]
MODEL_LAB_STD = 0.003


class DayLike(Protocol):
    """What a day needs to offer: :class:`~softsensor.recording.mcap_day.RecordedDay` and
    :class:`~softsensor.plant.simulator.SimulatedDay` both do."""

    scans: pd.DataFrame
    labs: pd.DataFrame


@dataclass(frozen=True)
class DayWindows:
    """A day as model windows.

    Attributes
    ----------
    start_ns : int
        First scan log time ``t0``. [ns since the Unix epoch, UTC]
    window_s : float
        Window length ``W``. [s]
    end_ns : numpy.ndarray, shape (K,)
        Window end times. [ns]
    U : numpy.ndarray, shape (K, 8)
        Model inputs in :data:`~softsensor.signals.INPUT_NAMES` order (SI). ``moisture_in`` is
        the config's nominal value.
    Y : numpy.ndarray, shape (K, 2)
        Measured window means of ``T_dryer_out`` and ``T_cyclone_out``, NaN when missing. [K]
    n_scans : numpy.ndarray, shape (K,)
        Scans in each window.
    n_good_out : numpy.ndarray, shape (K, 2)
        Good scans of ``T_dryer_out`` and ``T_cyclone_out`` in each window.
    air_edges : numpy.ndarray, shape (K + 1,)
        ``T_air_in`` at the window boundaries ``t0 + k W``. [K]
    lab_time_ns : numpy.ndarray, shape (L,)
        Stamped lab sample times within the windowed span, sorted. [ns]
    lab_value : numpy.ndarray, shape (L,)
        Lab ``moisture_out``. [kg/kg dry basis]
    lab_id : tuple of str
        Lab sample ids.
    held : dict[str, int]
        Per measured input, how many windows held a previous value.
    """

    start_ns: int
    window_s: float
    end_ns: np.ndarray
    U: np.ndarray
    Y: np.ndarray
    n_scans: np.ndarray
    n_good_out: np.ndarray
    air_edges: np.ndarray
    lab_time_ns: np.ndarray
    lab_value: np.ndarray
    lab_id: tuple[str, ...]
    held: dict[str, int]

    @property
    def n_windows(self) -> int:
        return int(self.U.shape[0])

    @property
    def hours(self) -> np.ndarray:
        """Window end times in hours from ``t0``. [h]"""
        return (self.end_ns - self.start_ns) / 3.6e12

    @property
    def lab_hours(self) -> np.ndarray:
        """Lab sample times in hours from ``t0``. [h]"""
        return (self.lab_time_ns - self.start_ns) / 3.6e12


def day_windows(day: DayLike, config: PlantConfig, source: str = "day") -> DayWindows:
    """Cut ``day`` into model windows (module docstring); ``source`` names it in errors.

    Raises :class:`~softsensor.errors.IngestError` when a scan column is missing or the day is
    shorter than ``MIN_WINDOWS`` windows.
    """
    scans = day.scans
    missing = [n for n in (*INPUT_NAMES[:-1], *KELVIN_CHANNELS) if n not in scans.columns]
    if missing:
        raise IngestError(f"{source}: signal {missing[0]} is missing from /plant/scan")
    if len(scans) == 0:
        raise IngestError(f"{source}: no /plant/scan messages")
    t = scans.index.to_numpy(dtype=np.int64)
    if np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        scans = scans.iloc[order]
        t = t[order]
    W = float(config.solver.window)
    w_ns = int(round(W * 1e9))
    t0 = int(t[0])
    span = (t[-1] - t0) / w_ns
    K = int(np.floor(span)) + (1 if span - np.floor(span) >= MIN_LAST_FRACTION else 0)
    if K < MIN_WINDOWS:
        raise IngestError(f"{source}: {span * W / 3600:.1f} h of scans; diagnosis needs at least "
                          f"{MIN_WINDOWS * W / 3600:g} h")
    k = np.clip((t - t0 - 1) // w_ns, 0, None)
    keep = k < K
    cols = [*INPUT_NAMES[:-1], *KELVIN_CHANNELS]
    frame = scans.loc[keep, cols]
    groups = frame.groupby(k[keep])
    means = groups.mean().reindex(range(K))
    n_scans = groups.size().reindex(range(K), fill_value=0).to_numpy(dtype=np.int64)
    n_good_out = groups[list(KELVIN_CHANNELS)].count().reindex(range(K), fill_value=0) \
        .to_numpy(dtype=np.int64)

    nominal = config.nominal
    U = np.empty((K, len(INPUT_NAMES)))
    held: dict[str, int] = {}
    for i, name in enumerate(INPUT_NAMES[:-1]):
        col = means[name].to_numpy(dtype=float)
        good = np.isfinite(col)
        held[name] = int((~good).sum())
        if not good.any():
            col = np.full(K, float(getattr(nominal, name)))
        elif not good.all():
            idx = np.where(good, np.arange(K), -1)
            idx = np.maximum.accumulate(idx)
            col = np.where(idx >= 0, col[np.maximum(idx, 0)], float(getattr(nominal, name)))
        U[:, i] = col
    U[:, -1] = float(nominal.moisture_in)
    Y = means[list(KELVIN_CHANNELS)].to_numpy(dtype=float)

    air_edges = _edges(t, scans["T_air_in"].to_numpy(dtype=float), t0, w_ns, K)
    air_edges = np.where(np.isfinite(air_edges), air_edges,
                         np.concatenate([U[:1, 0], U[:, 0]]))

    labs = day.labs
    if len(labs):
        lt = labs["sample_time_ns"].to_numpy(dtype=np.int64)
        lv = labs["moisture_out"].to_numpy(dtype=float)
        ids = [str(s) for s in labs["sample_id"]]
        inside = (lt >= t0) & (lt <= t0 + K * w_ns) & np.isfinite(lv)
        order = np.argsort(lt[inside], kind="stable")
        lab_t, lab_v = lt[inside][order], lv[inside][order]
        lab_ids = tuple(np.asarray(ids, dtype=object)[inside][order])
    else:
        lab_t, lab_v, lab_ids = np.zeros(0, np.int64), np.zeros(0), ()
    end_ns = t0 + (np.arange(K, dtype=np.int64) + 1) * w_ns
    return DayWindows(t0, W, end_ns, U, Y, n_scans, n_good_out, air_edges, lab_t, lab_v,
                      lab_ids, held)


def _edges(t: np.ndarray, x: np.ndarray, t0: int, w_ns: int, K: int) -> np.ndarray:
    """Mean of the good scans within ``EDGE_HALF_WIDTH`` of each boundary ``t0 + k W``."""
    bounds = t0 + np.arange(K + 1, dtype=np.int64) * w_ns
    half = int(EDGE_HALF_WIDTH * 1e9)
    good = np.isfinite(x)
    cs = np.concatenate([[0.0], np.cumsum(np.where(good, x, 0.0))])
    cn = np.concatenate([[0], np.cumsum(good)])
    lo = np.searchsorted(t, bounds - half, side="left")
    hi = np.searchsorted(t, bounds + half, side="right")
    n = cn[hi] - cn[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (cs[hi] - cs[lo]) / np.maximum(n, 1), np.nan)


def lab_model_values(end_ns: np.ndarray, y_model: np.ndarray, window_s: float,
                     sample_time_ns: np.ndarray) -> np.ndarray:
    """Model outlet moisture at lab sample times. [kg/kg]

    ``y_model`` are the model's outputs of the windows ending at ``end_ns`` [ns]. Run on a
    window's mean inputs, the quasi-steady model gives the window's *mean* output (on a clean
    virtual-plant day: 0.0008 kg/kg RMS from the true window mean, 0.0054 kg/kg from the true
    value at the window's end), so each output stands at its window's centre and a sample time
    is interpolated linearly between centres (before the first and after the last centre: the
    first and last value). What remains, about 0.003 kg/kg RMS, is the moisture's movement
    inside a window (:data:`MODEL_LAB_STD`).
    """
    centres = np.asarray(end_ns, float) - 0.5 * window_s * 1e9
    return np.interp(np.asarray(sample_time_ns, float), centres, y_model)


def lab_sse_by_shift(windows: DayWindows, y_model: np.ndarray, shifts_min: np.ndarray,
                     mask: np.ndarray | None = None) -> np.ndarray:
    """Sum of squared lab residuals [(kg/kg)^2] for every sample-time shift [min].

    The model's outlet moisture ``y_model`` (K,) is looked up (:func:`lab_model_values`) at the
    stamped sample times moved by each shift; ``mask`` selects the lab results (default all).
    """
    keep = np.ones(windows.lab_value.size, bool) if mask is None else np.asarray(mask, bool)
    ts = windows.lab_time_ns[keep].astype(float)
    y = windows.lab_value[keep]
    return np.array([np.sum((y - lab_model_values(windows.end_ns, y_model, windows.window_s,
                                                  ts + s * 60e9)) ** 2) for s in shifts_min])
