"""The peers a virtual sensor must beat, as a plant would build them (benchmarks only).

Every estimate is judged at the end of each 600 s estimator tick, knowing only the lab results
logged by then (each describing its earlier sample time):

* **hold**: the latest lab result that has arrived (by sample time), held.
* **regression**: the classic inferential sensor a plant engineer fits in a spreadsheet: a
  least-squares regression of the lab moisture on the 600 s means of every scanned signal at
  the sample time, fitted on the history's lab results, with the usual lab-bias update: at
  each arriving result the bias becomes the result minus the regression at its sample time,
  and is added until the next. The fit is the core's
  (:func:`softsensor.estimation.lab_regression.fit_lab_regression`), which the estimator
  also runs beside its physics.
* **time difference**: the latest lab result plus the change of the project's calibrated
  model, run open loop on the measured inputs at the history's inlet moisture, since that
  result's sample time (Kaneko and Funatsu's time-difference soft sensor, AIChE J. 57, 2011,
  on a physical model).
* **floor**: the plant's own effect-free physics run open loop on the measured inputs
  (:func:`softsensor.plant.independent.open_loop.open_loop_day`), with the same lab-bias
  update as the regression: what a perfect model of the plant, missing only what nobody
  measures, would publish. Also reported without the labs (``floor_open_loop``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from softsensor.estimation.lab_regression import (
    REGRESSION_SIGNALS,
    LabRegression,
    at_windows,
    fit_lab_regression,
    lab_features,
    window_means,
)

#: The regression peer is the core's (:mod:`softsensor.estimation.lab_regression`): the
#: estimator runs the same fit beside its physics, ``softsensor calibrate`` writes it.
Regression = LabRegression


def fit_regression(days: Sequence[object]) -> LabRegression:
    """The regression peer fitted on the lab results of ``days`` (scans and labs frames)."""
    return fit_lab_regression([lab_features(d.scans, d.labs) for d in days])


def _labs_by_arrival(labs: pd.DataFrame) -> list[dict]:
    return labs.sort_values(["log_time_ns", "sample_id"]).to_dict("records")


def hold_last_lab(labs: pd.DataFrame, ends: np.ndarray) -> np.ndarray:
    """The hold peer at every tick end (NaN before the first result arrives)."""
    out = np.full(len(ends), np.nan)
    known: list[dict] = []
    arrivals = _labs_by_arrival(labs)
    j = 0
    for k, e in enumerate(ends):
        while j < len(arrivals) and arrivals[j]["log_time_ns"] <= e:
            known.append(arrivals[j])
            j += 1
        if known:
            out[k] = max(known, key=lambda r: r["sample_time_ns"])["moisture_out"]
    return out


def bias_updated(labs: pd.DataFrame, ends: np.ndarray, at_sample: np.ndarray,
                 at_end: np.ndarray) -> np.ndarray:
    """An open-loop predictor with the classic lab-bias update: ``at_end + b`` where ``b`` is
    the last arrived result minus the predictor at its sample time (``at_sample``, one per
    lab in ``labs`` order); NaN before the first result."""
    order = np.argsort(labs["log_time_ns"].to_numpy(np.int64), kind="stable")
    log_t = labs["log_time_ns"].to_numpy(np.int64)[order]
    value = labs["moisture_out"].to_numpy(float)[order]
    pred = np.asarray(at_sample, float)[order]
    out = np.full(len(ends), np.nan)
    bias, j = math.nan, 0
    for k, e in enumerate(ends):
        while j < len(log_t) and log_t[j] <= e:
            if math.isfinite(pred[j]):
                bias = value[j] - pred[j]
            j += 1
        out[k] = at_end[k] + bias
    return out


def regression_peer(model: Regression, scans: pd.DataFrame, labs: pd.DataFrame,
                    ends: np.ndarray) -> np.ndarray:
    """The regression peer at every tick end."""
    wm = window_means(scans)[list(REGRESSION_SIGNALS)]
    at_sample = model.predict(at_windows(wm, labs["sample_time_ns"].to_numpy(np.int64)))
    at_end = model.predict(at_windows(wm, np.asarray(ends) - 1))
    return bias_updated(labs, ends, at_sample, at_end)


def series_at(series: pd.Series, times: np.ndarray) -> np.ndarray:
    """``series`` (indexed by time [ns]) at ``times``: its latest point at or before each
    (its first before it starts)."""
    t = series.index.to_numpy(np.int64)
    k = np.clip(np.searchsorted(t, np.asarray(times, np.int64), side="right") - 1, 0,
                len(t) - 1)
    return series.to_numpy(float)[k]


def time_difference(series: pd.Series, labs: pd.DataFrame, ends: np.ndarray) -> np.ndarray:
    """The latest arrived result plus ``series`` (a model's outlet moisture indexed by time
    [ns]) now minus at its sample time."""

    def at(times: np.ndarray) -> np.ndarray:
        return series_at(series, times)

    out = np.full(len(ends), np.nan)
    arrivals = _labs_by_arrival(labs)
    known: list[dict] = []
    j = 0
    now = at(np.asarray(ends, np.int64))
    for k, _ in enumerate(ends):
        while j < len(arrivals) and arrivals[j]["log_time_ns"] <= ends[k]:
            known.append(arrivals[j])
            j += 1
        if known:
            last = max(known, key=lambda r: r["sample_time_ns"])
            then = at(np.array([last["sample_time_ns"]], np.int64))[0]
            out[k] = last["moisture_out"] + now[k] - then
    return out


def series_peer(series: pd.Series, labs: pd.DataFrame, ends: np.ndarray) -> np.ndarray:
    """``series`` (indexed by time [ns]) with the lab-bias update, at every tick end."""
    return bias_updated(labs, ends, series_at(series, labs["sample_time_ns"].to_numpy()),
                        series_at(series, ends))


__all__ = ["REGRESSION_SIGNALS", "Regression", "at_windows", "bias_updated", "fit_regression",
           "hold_last_lab", "regression_peer", "series_at", "series_peer", "time_difference",
           "window_means"]
