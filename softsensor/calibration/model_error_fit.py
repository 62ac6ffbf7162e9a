"""Learning the model's error from the plant's history: :class:`~softsensor.estimation.
model_error.ModelError` (PARAMS.toml's ``[model_error]``).

Given the calibrated parameters and the history's days (each a whole-day
:class:`~.dataset.Segment`), :func:`fit_model_error`:

1. runs the model open loop on every day's measured inputs, at the history's typical inlet
   moisture (the mean of the calibration's day levels), and takes the residuals of the two
   outlet temperatures (window means) and of the lab results (at their sample times);
2. per channel, regresses them on the standardised operating point (:data:`~softsensor.
   estimation.model_error.FEATURES`) with one free offset per day (fixed effects, so a day's
   level, its inlet moisture and its weather, does not pass for a response to the operating
   point) and a ridge penalty on the slopes chosen by leave-one-day-out cross-validation
   (leave one quarter-day out when fewer than three days are given); a channel whose slopes do
   not predict held-out days better than none gets none;
3. sizes what is left: the spread of the day offsets (less what their own estimation noise
   explains) and their covariance across the channels (:func:`day_covariance`), a level
   walk that moves it within :data:`LEVEL_MOVES_IN_H`, and from the semivariogram of the
   within-day residuals white noise and a first-order wander (:func:`wander`; Cressie,
   *Statistics for Spatial Data*, 1993, ch. 2: the exponential model);
4. the slopes' covariance: the ridge estimator's sandwich with the residual variance,
   inflated for serial correlation by ``(1 + rho) / (1 - rho)`` (``rho``: the lag-one
   autocorrelation of the residuals; windows of one day are not independent samples).

Everything is linear algebra on one open-loop run per day, so it costs one simulation of the
history (seconds for weeks).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softsensor.calibration.chunked_run import simulate_segments
from softsensor.calibration.dataset import Segment
from softsensor.errors import IngestError
from softsensor.estimation.model_error import CHANNELS, FEATURES, ChannelError, ModelError
from softsensor.model import DryerModel
from softsensor.signals import INPUT_NAMES

#: Ridge penalties tried (per sample, on standardised features) [-].
RIDGE_GRID: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 1e-1, 1.0)
#: Residuals a channel needs per slope (plus the intercept) to learn slopes at all: a
#: few days of lab results (about eight a day) learn them; a day or two does not.
MIN_SAMPLES_PER_FEATURE = 3
#: Lag bins of the within-day variogram [h].
LAG_EDGES_H = np.array([0.0, 0.2, 0.4, 0.75, 1.5, 3.0, 6.0, 12.0, 24.0])
#: The time over which a channel's day level may move by its day-to-day spread (its
#: random walk in a daemon that runs across days) [h].
LEVEL_MOVES_IN_H = 24.0
#: A held-out RMSE must be below this share of the RMSE without the discrepancy for it to be
#: kept: a slope that buys less than 2 % is noise, not a response to learn.
KEEP_BELOW = 0.98

_MI = INPUT_NAMES.index("moisture_in")


@dataclass(frozen=True)
class _Rows:
    """One channel's residuals of every day: values, standardised features, day index,
    times [h] from the day's start."""

    r: np.ndarray
    phi: np.ndarray
    day: np.ndarray
    t_h: np.ndarray


def feature_columns(seg: Segment) -> dict[str, np.ndarray]:
    """Window means of :data:`~softsensor.estimation.model_error.FEATURES` of a segment, by name
    (K,)."""
    cols = {name: seg.U[:, i] for i, name in enumerate(INPUT_NAMES[:-1])}
    cols["T_sp"] = np.asarray(seg.T_sp, float)
    return cols


def at_inlet_moisture(seg: Segment, level: float) -> Segment:
    """``seg`` with the model's inlet moisture at ``level`` [kg/kg] everywhere."""
    U = seg.U.copy()
    U[:, _MI] = level
    lab_U = seg.lab_U.copy()
    lab_U[:, _MI] = level
    return dataclasses.replace(seg, U=U, lab_U=lab_U)


def _standardise(segments: Sequence[Segment]) -> tuple[np.ndarray, np.ndarray]:
    """Means and standard deviations of the features over every window (a constant feature
    gets scale 1)."""
    X = np.vstack([np.column_stack([feature_columns(s)[f] for f in FEATURES])
                   for s in segments])
    mean = np.nanmean(X, axis=0)
    scale = np.nanstd(X, axis=0)
    mean = np.where(np.isfinite(mean), mean, 0.0)
    scale = np.where(np.isfinite(scale) & (scale > 1e-9 * np.maximum(np.abs(mean), 1.0)),
                     scale, 1.0)
    return mean, scale


def _rows(segments: Sequence[Segment], runs, channel: int, mean: np.ndarray,
          scale: np.ndarray) -> _Rows:
    """Residuals (measured - model) of ``channel`` on every day, with their features."""
    r, phi, day, t = [], [], [], []
    for i, (seg, run) in enumerate(zip(segments, runs, strict=True)):
        X = (np.column_stack([feature_columns(seg)[f] for f in FEATURES]) - mean) / scale
        X = np.where(np.isfinite(X), X, 0.0)
        if channel < 2:
            res = seg.Y[:, channel] - run.Y[0, :, channel]
            t_h = np.arange(1, seg.n_windows + 1) * seg.window / 3600.0
            ok = np.isfinite(res)
            r.append(res[ok])
            phi.append(X[ok])
            t.append(t_h[ok])
        else:
            res = seg.lab_value - run.lab[0]
            ok = np.isfinite(res)
            r.append(res[ok])
            phi.append(X[seg.lab_window][ok])
            t.append(((seg.lab_time_ns - seg.start_ns) / 3.6e12)[ok])
        day.append(np.full(int(ok.sum()), i))
    return _Rows(np.concatenate(r), np.vstack(phi), np.concatenate(day), np.concatenate(t))


def _folds(rows: _Rows, n_days: int) -> np.ndarray:
    """Fold of every row: its day, or with fewer than three days its quarter-day block."""
    if n_days >= 3:
        return rows.day
    span = max(float(rows.t_h.max()) if rows.t_h.size else 1.0, 1e-9)
    return rows.day * 4 + np.minimum((rows.t_h / span * 4).astype(int), 3)


def _fit(rows: _Rows, keep: np.ndarray, groups: np.ndarray, ridge: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """Slopes and per-group offsets of the rows ``keep`` (fixed effects, ridge on slopes)."""
    g_ids, g = np.unique(groups[keep], return_inverse=True)
    n, F = int(keep.sum()), rows.phi.shape[1]
    A = np.hstack([np.eye(len(g_ids))[g], rows.phi[keep]])
    pen = np.r_[np.zeros(len(g_ids)), np.full(F, ridge * n)]
    coef = np.linalg.solve(A.T @ A + np.diag(pen) + 1e-12 * np.eye(A.shape[1]),
                           A.T @ rows.r[keep])
    return coef[len(g_ids):], coef[:len(g_ids)]


def _within(r: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """``r`` less its group means."""
    out = r.copy()
    for g in np.unique(groups):
        m = groups == g
        out[m] -= r[m].mean()
    return out


def _held_out(rows: _Rows, folds: np.ndarray, ridge: float) -> float:
    """Within-fold RMSE of the residuals after slopes fitted on the other folds."""
    err = np.empty_like(rows.r)
    for f in np.unique(folds):
        test = folds == f
        if test.all():
            err[test] = _within(rows.r[test], folds[test])
            continue
        beta, _ = _fit(rows, ~test, folds, ridge)
        left = rows.r[test] - rows.phi[test] @ beta
        err[test] = left - left.mean()
    return float(np.sqrt(np.mean(err**2)))


def _lag1(e: np.ndarray, groups: np.ndarray) -> float:
    """Lag-one autocorrelation of ``e`` within groups (0 when it cannot be measured)."""
    num = den = 0.0
    for g in np.unique(groups):
        x = e[groups == g]
        if x.size > 2:
            num += float(np.sum(x[1:] * x[:-1]))
            den += float(np.sum(x * x))
    return float(np.clip(num / den, 0.0, 0.99)) if den > 0 else 0.0


def variogram(e: np.ndarray, t_h: np.ndarray, groups: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The within-day empirical variogram of ``e`` at sample times ``t_h`` [h]: per lag bin
    of :data:`LAG_EDGES_H`, the mean lag, half the mean squared difference of the pairs that
    far apart in the same group, and the pair count."""
    sums = np.zeros((len(LAG_EDGES_H) - 1, 3))
    for g in np.unique(groups):
        m = groups == g
        x, t = e[m], t_h[m]
        iu = np.triu_indices(len(x), 1)
        lag = np.abs(t[:, None] - t[None, :])[iu]
        d2 = ((x[:, None] - x[None, :]) ** 2)[iu]
        b = np.digitize(lag, LAG_EDGES_H) - 1
        ok = (b >= 0) & (b < len(LAG_EDGES_H) - 1)
        np.add.at(sums, b[ok], np.column_stack([lag[ok], 0.5 * d2[ok], np.ones(ok.sum())]))
    n = sums[:, 2]
    seen = n > 0
    return (sums[seen, 0] / n[seen], sums[seen, 1] / n[seen], n[seen])


def wander(e: np.ndarray, t_h: np.ndarray, groups: np.ndarray) -> tuple[float, float, float]:
    """White noise [unit], and standard deviation [unit] and correlation time [h] of the
    first-order (Ornstein-Uhlenbeck) wander of ``e``, fitted to its within-day semivariogram
    ``gamma(lag) = noise^2 + sd^2 (1 - exp(-lag / tau))`` by weighted least squares (each
    bin by its pair count). On the independent plant's clean days the temperature residuals'
    semivariogram levels off within about eight hours: the model's error wanders about its
    day level (sd about 0.25 K, tau a few hours) rather than walking away from it."""
    from scipy.optimize import least_squares

    lag, gam, n = variogram(e, t_h, groups)
    total = float(np.var(e)) if e.size else 0.0
    if lag.size < 3:
        return math.sqrt(total), 0.0, 1.0
    w = np.sqrt(n / n.sum())

    def res(p: np.ndarray) -> np.ndarray:
        n2, s2, tau = p
        return w * (n2 + s2 * (1.0 - np.exp(-lag / tau)) - gam)

    hi = max(total, float(gam.max()), 1e-30) * 4.0
    x0 = [0.5 * float(gam[0]), max(float(gam.max() - gam[0]), 1e-30), 2.0]
    sol = least_squares(res, np.clip(x0, [0, 0, 0.1], [hi, hi, 48.0]),
                        bounds=([0.0, 0.0, 0.1], [hi, hi, 48.0]))
    n2, s2, tau = sol.x
    return math.sqrt(n2), math.sqrt(s2), float(tau)


def _without_slopes(rows: _Rows, F: int) -> ChannelError:
    """A channel with too few residuals to learn slopes from: its mean offset and its
    scatter only (no slopes, no day spread, no walk)."""
    r = rows.r
    within = float(np.sqrt(np.mean(_within(r, rows.day) ** 2))) if r.size else 0.0
    return ChannelError(coef=(0.0,) * F, coef_cov=(0.0,) * (F * F),
                        intercept=float(np.mean(r)) if r.size else 0.0, day_sd=0.0, walk=0.0,
                        noise=within, rmse_without=within, rmse_held_out=within,
                        samples=int(r.size))


def _channel(rows: _Rows, n_days: int) -> ChannelError:
    """Fit one channel (module docstring, steps 2 to 4)."""
    F = rows.phi.shape[1]
    if rows.r.size < MIN_SAMPLES_PER_FEATURE * (F + 1):
        return _without_slopes(rows, F)
    folds = _folds(rows, n_days)
    without = float(np.sqrt(np.mean(_within(rows.r, rows.day) ** 2)))
    scores = {lam: _held_out(rows, folds, lam) for lam in RIDGE_GRID}
    ridge = min(scores, key=scores.get)
    held = scores[ridge]
    beta, offsets = _fit(rows, np.ones(rows.r.size, bool), rows.day, ridge)
    if not held < KEEP_BELOW * without:
        beta = np.zeros(F)
        _, offsets = _fit(rows, np.ones(rows.r.size, bool), rows.day, 1e12)
        held = without
    e = rows.r - rows.phi @ beta - offsets[np.unique(rows.day, return_inverse=True)[1]]
    noise, wander_sd, wander_tau_h = wander(e, rows.t_h, rows.day)
    counts = np.bincount(np.unique(rows.day, return_inverse=True)[1])
    spread = float(np.var(offsets)) - float(np.mean(np.var(e) / counts))
    day_sd = math.sqrt(max(spread, 0.0)) if len(offsets) > 1 else 0.0
    walk = day_sd / math.sqrt(LEVEL_MOVES_IN_H)
    cov = np.zeros((F, F))
    if np.any(beta != 0.0):
        rho = _lag1(e, rows.day)
        _, g = np.unique(rows.day, return_inverse=True)
        group_mean = np.stack([np.bincount(g, rows.phi[:, j]) for j in range(F)], 1)
        X = rows.phi - (group_mean / np.bincount(g)[:, None])[g]
        G = np.linalg.inv(X.T @ X + ridge * rows.r.size * np.eye(F))
        cov = float(np.var(e)) * (1 + rho) / (1 - rho) * (G @ (X.T @ X) @ G)
        cov = 0.5 * (cov + cov.T)
    return ChannelError(coef=tuple(map(float, beta)), coef_cov=tuple(map(float, cov.ravel())),
                        intercept=float(np.mean(offsets)), day_sd=day_sd, walk=walk,
                        noise=noise, wander_sd=wander_sd, wander_tau_h=wander_tau_h,
                        rmse_without=without, rmse_held_out=held, samples=int(rows.r.size))


def _day_offsets(rows: _Rows, beta: np.ndarray) -> dict[int, tuple[float, float]]:
    """Each day's offset of a channel's residuals after its slopes, and that offset's own
    estimation variance (the day's within scatter over its sample count)."""
    e = rows.r - rows.phi @ np.asarray(beta, float)
    out = {}
    for d in np.unique(rows.day):
        x = e[rows.day == d]
        out[int(d)] = (float(x.mean()), float(x.var()) / max(x.size, 1))
    return out


def day_covariance(offsets: Sequence[dict[int, tuple[float, float]]]) -> np.ndarray | None:
    """Covariance (C, C) of the channels' day offsets over the days all channels have, less
    the offsets' own estimation noise on the diagonal, kept positive semi-definite (step 3
    of the module docstring for every channel at once). The outlet temperatures' day
    offsets move together (one energy balance: corr 0.99 on the independent plant) while a
    thermometer's offset moves one; the labs' day offset follows them too (the day's feed)."""
    days = sorted(set.intersection(*(set(o) for o in offsets)))
    if len(days) < 3:
        return None  # too few days for a covariance: each channel's spread alone
    levels = np.array([[o[d][0] for o in offsets] for d in days])
    cov = np.cov(levels, rowvar=False)
    noise = np.array([np.mean([o[d][1] for d in days]) for o in offsets])
    cov = cov - np.diag(noise)
    w, V = np.linalg.eigh(0.5 * (cov + cov.T))
    return (V * np.clip(w, 0.0, None)) @ V.T


def fit_model_error(model: DryerModel, days: Sequence[Segment], theta: np.ndarray,
                    moisture_in: float, moisture_in_day_sd: float = 0.0,
                    latest_moisture_in: float = 0.0) -> ModelError:
    """Learn :class:`ModelError` from whole history ``days`` at parameters ``theta`` (7,)
    with the model's inlet moisture at ``moisture_in`` [kg/kg] (module docstring);
    ``latest_moisture_in``: the latest day's level, the estimator's start (0: none).

    Raises :class:`~softsensor.errors.IngestError` when a day cannot be simulated or there
    are too few residuals (a lab channel needs more lab results than features, over the days).
    """
    if not days:
        raise IngestError("no history day to learn the model error from")
    segs = [at_inlet_moisture(s, moisture_in) for s in days]
    runs = simulate_segments(model, segs, np.asarray(theta, float))
    for seg, run in zip(segs, runs, strict=True):
        if run.failed[0]:
            raise IngestError(f"{seg.source}: the model cannot be solved on this day at the "
                              f"calibrated parameters")
    mean, scale = _standardise(segs)
    rows = [_rows(segs, runs, c, mean, scale) for c in range(len(CHANNELS))]
    channels = {name: _channel(r, len(segs)) for name, r in zip(CHANNELS, rows, strict=True)}
    cov = day_covariance([_day_offsets(r, channels[name].coef)
                          for name, r in zip(CHANNELS, rows, strict=True)])
    return ModelError(features=FEATURES, mean=tuple(map(float, mean)),
                      scale=tuple(map(float, scale)), days=len(segs),
                      hours=float(sum(s.hours for s in segs)), moisture_in=float(moisture_in),
                      moisture_in_day_sd=float(moisture_in_day_sd),
                      latest_moisture_in=float(latest_moisture_in),
                      day_cov=() if cov is None else tuple(map(float, cov.ravel())),
                      **channels)


__all__ = ["RIDGE_GRID", "at_inlet_moisture", "feature_columns", "fit_model_error"]
