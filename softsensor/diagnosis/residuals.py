"""Statistics of model residuals: what the calibrated model gets wrong, channel by channel.

For each temperature channel (window residuals ``r_k`` = measured window mean minus model,
[K]) :func:`channel_stats` computes

* bias: the mean and its t value, with the standard error inflated for autocorrelation by
  the effective sample size ``n_eff = n (1 - rho_1) / (1 + rho_1)`` (``rho_1`` the lag-1
  autocorrelation, clipped at 0);
* trend: the least-squares slope over time [K/h] and its t value (same ``n_eff``);
* whiteness: the Ljung-Box statistic ``Q = n (n + 2) sum_{j=1..h} rho_j^2 / (n - j)`` over
  ``h = 10`` lags and its p value (chi-square, ``h`` degrees of freedom);
* the biggest change of mean: the split maximising the two-sample t value of the means
  before and after (a CUSUM-type change-point scan; the maximum over splits is not a
  calibrated test, so it is reported, not thresholded);
* the cross-correlation with every measured input and with its window-to-window rate of
  change, at lags ``-3..3`` windows (the residual lagging the input for positive lags),
  keeping the lag of largest magnitude;
* the dependence on ambient conditions: the regression slope on ``T_amb`` [K/K] and its t
  value, and the correlation with ``H_amb``.

For the lab channel (:func:`lab_stats`, residuals at lab sample times [kg/kg]): mean, trend,
the correlation with the model's rate of change at the sample time (what a wrong sample time
produces: ``r ~ -delta dy/dt``), and the lab RMSE as the stamped times are moved by
``-90..90`` min (lagged cross-correlation of the lab residuals), with the best shift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from softsensor.calibration.identifiability import lag1_autocorrelation as lag1
from softsensor.diagnosis.day_windows import DayWindows
from softsensor.signals import INPUT_NAMES

#: Lags of the Ljung-Box test.
LJUNG_BOX_LAGS = 10
#: Largest lag (windows) of the input cross-correlations.
MAX_XCORR_LAG = 3
#: Fewest windows on either side of a change point.
MIN_SEGMENT = 6
#: Lab time shifts scanned. [min]
LAB_SHIFTS_MIN = np.arange(-90.0, 90.0 + 1e-9, 2.0)


@dataclass(frozen=True)
class CrossCorrelation:
    """Largest-magnitude correlation of a residual with a series over lags ``-3..3``."""

    corr: float
    lag: int


@dataclass(frozen=True)
class ChannelStats:
    """Residual statistics of one temperature channel (module docstring). Units: K, h."""

    channel: str
    n: int
    mean: float
    t_mean: float
    rmse: float
    noise: float
    rho1: float
    slope_per_h: float
    t_slope: float
    ljung_box_q: float
    ljung_box_p: float
    change_hour: float
    change_shift: float
    change_t: float
    xcorr: dict[str, CrossCorrelation]
    xcorr_rate: dict[str, CrossCorrelation]
    amb_slope: float
    t_amb_slope: float
    corr_H_amb: float

    @property
    def structure_ratio(self) -> float:
        """RMSE over the window-to-window noise level (1 for white noise)."""
        return self.rmse / self.noise if self.noise > 0 else math.inf


@dataclass(frozen=True)
class LabStats:
    """Residual statistics of the lab channel (module docstring). Units: kg/kg, h, min."""

    n: int
    mean: float
    rmse: float
    slope_per_h: float
    corr_model_rate: float
    best_shift_min: float
    rmse_at_best_shift: float


def effective_n(n: int, rho1: float) -> float:
    """Effective sample size of an AR(1)-like series, ``n (1 - rho) / (1 + rho)``, rho >= 0."""
    rho = min(max(rho1, 0.0), 0.99)
    return max(n * (1.0 - rho) / (1.0 + rho), 2.0)


def ljung_box(r: np.ndarray, lags: int = LJUNG_BOX_LAGS) -> tuple[float, float]:
    """Ljung-Box ``Q`` and its p value (chi-square with ``lags`` degrees of freedom)."""
    r = r[np.isfinite(r)]
    n = r.size
    h = min(lags, n - 2)
    if h < 1:
        return 0.0, 1.0
    d = r - r.mean()
    den = float(d @ d)
    if den <= 0:
        return 0.0, 1.0
    rho = np.array([d[j:] @ d[:-j] / den for j in range(1, h + 1)])
    q = float(n * (n + 2) * np.sum(rho**2 / (n - np.arange(1, h + 1))))
    return q, float(stats.chi2.sf(q, h))


def _slope(x: np.ndarray, r: np.ndarray, n_eff: float) -> tuple[float, float]:
    """Least-squares slope of ``r`` on ``x`` and its t value with ``n_eff`` samples."""
    ok = np.isfinite(r) & np.isfinite(x)
    x, r = x[ok], r[ok]
    if x.size < 3 or np.ptp(x) == 0:
        return 0.0, 0.0
    xc = x - x.mean()
    b = float(xc @ (r - r.mean()) / (xc @ xc))
    resid = r - r.mean() - b * xc
    s2 = float(resid @ resid) / max(x.size - 2, 1)
    se = math.sqrt(s2 / float(xc @ xc) * x.size / max(n_eff, 1.0))
    return b, (b / se if se > 0 else 0.0)


def change_point(r: np.ndarray, hours: np.ndarray) -> tuple[float, float, float]:
    """Biggest change of mean: ``(hour, shift after - before, t)``.

    Every split with at least ``MIN_SEGMENT`` windows on each side is tried; the t value uses
    the pooled standard deviation about the two means, inflated for the lag-1
    autocorrelation left at the best split (``n / n_eff``).
    """
    ok = np.isfinite(r)
    r, h = r[ok], hours[ok]
    n = r.size
    if n < 2 * MIN_SEGMENT:
        return float("nan"), 0.0, 0.0
    cs = np.cumsum(r)
    cs2 = np.cumsum(r * r)
    i = np.arange(MIN_SEGMENT, n - MIN_SEGMENT + 1)
    before = cs[i - 1] / i
    after = (cs[-1] - cs[i - 1]) / (n - i)
    ss = cs2[-1] - i * before**2 - (n - i) * after**2
    s = np.sqrt(np.maximum(ss, 1e-300) / (n - 2))
    t = (after - before) / (s * np.sqrt(1.0 / i + 1.0 / (n - i)))
    j = int(np.argmax(np.abs(t)))
    split = i[j]
    left = np.concatenate([r[:split] - before[j], r[split:] - after[j]])
    inflate = math.sqrt(n / effective_n(n, lag1(left)))
    return float(h[split - 1]), float(after[j] - before[j]), float(t[j] / inflate)


def cross_correlation(r: np.ndarray, x: np.ndarray, max_lag: int = MAX_XCORR_LAG
                      ) -> CrossCorrelation:
    """Correlation of ``r[k]`` with ``x[k - lag]`` for ``lag`` in ``-max_lag..max_lag``;
    the lag of largest magnitude."""
    best = CrossCorrelation(0.0, 0)
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            a, b = r[lag:], x[:x.size - lag]
        else:
            a, b = r[:lag], x[-lag:]
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 8 or np.std(a[ok]) == 0 or np.std(b[ok]) == 0:
            continue
        c = float(np.corrcoef(a[ok], b[ok])[0, 1])
        if abs(c) > abs(best.corr):
            best = CrossCorrelation(c, lag)
    return best


def channel_stats(name: str, r: np.ndarray, windows: DayWindows, noise: float
                  ) -> ChannelStats:
    """Statistics of the window residuals ``r`` (K,) of temperature channel ``name``."""
    ok = np.isfinite(r)
    n = int(ok.sum())
    rr = r[ok]
    rho = lag1(r)
    n_eff = effective_n(n, rho)
    mean = float(rr.mean()) if n else 0.0
    sd = float(rr.std(ddof=1)) if n > 1 else 0.0
    t_mean = mean / (sd / math.sqrt(n_eff)) if sd > 0 else 0.0
    hours = windows.hours
    slope, t_slope = _slope(hours, r, n_eff)
    q, p = ljung_box(r)
    ch_hour, ch_shift, ch_t = change_point(r, hours)
    U = windows.U
    xcorr, xrate = {}, {}
    for j, inp in enumerate(INPUT_NAMES[:-1]):
        xcorr[inp] = cross_correlation(r, U[:, j])
        xrate[inp] = cross_correlation(r, np.concatenate([[np.nan], np.diff(U[:, j])]))
    T_amb = U[:, INPUT_NAMES.index("T_amb")]
    amb, t_amb = _slope(T_amb, r, n_eff)
    H_amb = U[:, INPUT_NAMES.index("H_amb")]
    c_h = cross_correlation(r, H_amb, 0).corr
    return ChannelStats(name, n, mean, t_mean, float(np.sqrt(np.mean(rr**2))) if n else 0.0,
                        noise, rho, slope, t_slope, q, p, ch_hour, ch_shift, ch_t, xcorr,
                        xrate, amb, t_amb, c_h)


def lab_stats(r: np.ndarray, windows: DayWindows, y_model: np.ndarray,
              shifted: np.ndarray) -> LabStats:
    """Statistics of the lab residuals ``r`` (L,) of the model's outlet moisture: ``y_model``
    (K,) of every window gives its rate of change, ``shifted`` (S, L) the model at the sample
    times moved by each of :data:`LAB_SHIFTS_MIN`."""
    n = int(r.size)
    if n == 0:
        return LabStats(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    slope = _slope(windows.lab_hours, r, n)[0] if n >= 3 else 0.0
    rate = np.gradient(y_model, windows.window_s / 3600.0)  # kg/kg per h
    # the rate at a sample time: each window's value stands at its centre
    centres = windows.end_ns.astype(float) - 0.5 * windows.window_s * 1e9
    rate_at = np.interp(windows.lab_time_ns.astype(float), centres, rate)
    corr = (float(np.corrcoef(r, rate_at)[0, 1])
            if n >= 3 and np.std(r) > 0 and np.std(rate_at) > 0 else 0.0)
    rmse = np.sqrt(np.mean((windows.lab_value[None, :] - shifted) ** 2, axis=1))
    rmse = np.where(np.isfinite(rmse), rmse, np.inf)
    i = int(np.argmin(rmse))
    return LabStats(n, float(r.mean()), float(np.sqrt(np.mean(r**2))), slope, corr,
                    float(LAB_SHIFTS_MIN[i]), float(rmse[i]))
