"""The plant's own inferential sensor, kept inside the virtual sensor: a linear regression of
the lab moisture on the scanned signals, with the lab-bias update.

This is the classic peer a plant engineer fits in a spreadsheet (Kadlec, Gabrys and Strandt,
Comput. Chem. Eng. 33, 2009, section 4.3): least squares (with a whisper of ridge,
:data:`RIDGE`) of the lab's ``moisture_out`` on the 600 s means of every scanned signal at the
sample time (:data:`REGRESSION_SIGNALS`), fitted on the history's lab results; at each arriving
result the bias becomes the result minus the regression at its sample time, and is added until
the next. One rule in one place: ``softsensor calibrate`` fits it on the history it calibrates
on and writes it to PARAMS.toml's ``[regression]`` (:meth:`LabRegression.to_table`), the
estimator runs it beside the physics (:mod:`.peer_blend`), and the benchmarks' regression peer
(``benchmarks/peers.py``) is this fit.

Beside the coefficients the fit keeps how well the two simple peers predicted the *next* lab
result on the history (consecutive results of one day): ``step_sd``, the standard deviation
of the bias-updated regression's error, and ``hold_sd``, that of holding the last result. They
are each peer's predictive spread when the estimator weighs it by its lab likelihood.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from softsensor.errors import ConfigError
from softsensor.plantconfig import PlantConfig, built_table
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.accumulator import window_end

if TYPE_CHECKING:  # the frames are the callers': the daemon runs without pandas (issue 49)
    import pandas as pd

#: Signals of the regression: every scanned signal (a spreadsheet takes them all).
REGRESSION_SIGNALS: tuple[str, ...] = tuple(SCAN_SIGNALS)
#: Ridge of the regression per lab sample, on standardised signals.
RIDGE = 0.01
#: Window of the signal means the regression reads [ns] (the estimator's tick).
W_NS = 600 * 10**9


def window_means(scans: pd.DataFrame, period_ns: int = W_NS) -> pd.DataFrame:
    """``period_ns`` means of every scanned signal, indexed by window end [ns]
    (``(start, end]``)."""
    ends = window_end(scans.index.to_numpy(np.int64), period_ns)
    return scans.groupby(ends).mean()


def at_windows(frame: pd.DataFrame, t_ns: np.ndarray, period_ns: int = W_NS) -> np.ndarray:
    """Rows of ``frame`` (indexed by window end) for the windows holding times ``t_ns``."""
    return frame.reindex(window_end(np.asarray(t_ns, np.int64), period_ns)).to_numpy(float)


def lab_features(scans: pd.DataFrame, labs: pd.DataFrame,
                 signals: Sequence[str] = REGRESSION_SIGNALS) -> tuple[np.ndarray, np.ndarray]:
    """The regression's rows of one recorded day: the signals' window means at each lab
    result's sample time and its ``moisture_out``, in sample-time order; rows with a missing
    signal or value dropped."""
    labs = labs.sort_values("sample_time_ns", kind="stable")
    wm = window_means(scans).reindex(columns=list(signals))
    F = at_windows(wm, labs["sample_time_ns"].to_numpy(np.int64))
    y = labs["moisture_out"].to_numpy(float)
    ok = np.all(np.isfinite(F), axis=1) & np.isfinite(y)
    return F[ok], y[ok]


@dataclass(frozen=True)
class LabRegression:
    """Coefficients on standardised signals (intercept first), the signals' means and
    scales, and the history's next-lab error spreads of the two simple peers (module
    docstring)."""

    signals: tuple[str, ...]
    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    step_sd: float
    hold_sd: float
    n_labs: int

    def predict(self, X: np.ndarray) -> np.ndarray:
        """The regression at rows ``X`` (signals in :attr:`signals` order); a missing signal
        is taken at its history mean."""
        Z = (np.asarray(X, float) - self.mean) / self.scale
        Z = np.where(np.isfinite(Z), Z, 0.0)
        return self.coef[0] + Z @ self.coef[1:]

    def at_means(self, means: Mapping[str, float | None]) -> float:
        """The regression at one window's means (``Window.means``; ``None`` is missing)."""
        row = np.array([math.nan if means.get(s) is None else float(means[s])  # type: ignore[arg-type]
                        for s in self.signals])
        return float(self.predict(row[None, :])[0])

    def to_table(self) -> dict[str, Any]:
        """PARAMS.toml's ``[regression]``."""
        return {"signals": list(self.signals), "mean": [float(v) for v in self.mean],
                "scale": [float(v) for v in self.scale],
                "coef": [float(v) for v in self.coef], "step_sd": float(self.step_sd),
                "hold_sd": float(self.hold_sd), "n_labs": int(self.n_labs)}

    @classmethod
    def from_table(cls, table: Any, source: str) -> LabRegression:
        """Inverse of :meth:`to_table`; :class:`ConfigError` naming the key that is wrong."""
        where = f"{source}: [regression]"
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where} must be a table")
        missing = [k for k in ("signals", "mean", "scale", "coef", "step_sd", "hold_sd")
                   if k not in table]
        if missing:
            raise ConfigError(f"{where} lacks {', '.join(missing)}")
        signals = table["signals"]
        if (not isinstance(signals, list) or not signals
                or any(s not in SCAN_SIGNALS for s in signals)):
            raise ConfigError(f"{where}.signals must list scanned signals, got {signals!r}")
        n = len(signals)

        def vector(key: str, size: int) -> np.ndarray:
            v = table[key]
            if (not isinstance(v, list) or len(v) != size
                    or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v)
                    or not all(math.isfinite(x) for x in v)):
                raise ConfigError(f"{where}.{key} must be {size} finite numbers")
            return np.array(v, float)

        def positive(key: str) -> float:
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1:
                raise ConfigError(f"{where}.{key} must be a number in (0, 1) kg/kg, got {v!r}")
            return float(v)

        scale = vector("scale", n)
        if np.any(scale <= 0):
            raise ConfigError(f"{where}.scale must be positive")
        return cls(tuple(signals), vector("mean", n), scale, vector("coef", n + 1),
                   positive("step_sd"), positive("hold_sd"), int(table.get("n_labs", 0)))


def _step_sd(errors: Sequence[np.ndarray]) -> float:
    """Standard deviation of the change between consecutive entries of each day's
    ``errors`` (what a peer anchored at the last lab result misses at the next one)."""
    d = np.concatenate([np.diff(e) for e in errors if len(e) > 1] or [np.zeros(0)])
    return float(np.sqrt(np.mean(d**2))) if len(d) else math.nan


def fit_lab_regression(days: Sequence[tuple[np.ndarray, np.ndarray]],
                       signals: Sequence[str] = REGRESSION_SIGNALS) -> LabRegression:
    """Fit the regression on the history: ``days`` holds per day the rows ``X`` (signals in
    ``signals`` order) and lab values ``y`` in sample-time order (:func:`lab_features`).

    Raises :class:`ConfigError` when the history holds fewer lab results than coefficients.
    """
    Xa = np.vstack([np.asarray(X, float).reshape(-1, len(signals)) for X, _ in days])
    ya = np.concatenate([np.asarray(y, float) for _, y in days])
    if len(ya) < len(signals) + 1:
        raise ConfigError(f"the regression peer needs at least {len(signals) + 1} lab results "
                          f"with every signal scanned, the history holds {len(ya)}")
    mean, scale = Xa.mean(axis=0), Xa.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    A = np.column_stack([np.ones(len(Xa)), (Xa - mean) / scale])
    # a whisper of ridge (1 % of a sample's weight per standardised signal) keeps a short
    # history with collinear signals from extrapolating wildly; with weeks of labs it is OLS
    pen = np.r_[0.0, np.full(A.shape[1] - 1, RIDGE * len(ya))]
    coef = np.linalg.solve(A.T @ A + np.diag(pen), A.T @ ya)
    reg = LabRegression(tuple(signals), mean, scale, coef, math.nan, math.nan, len(ya))
    residuals = [np.asarray(y, float) - reg.predict(X) for X, y in days]
    floor = 1e-4  # a history of one result per day says nothing of the step: no zero spread
    step = _step_sd(residuals)
    hold = _step_sd([np.asarray(y, float) for _, y in days])
    return LabRegression(tuple(signals), mean, scale, coef,
                         max(step, floor) if math.isfinite(step) else float(np.std(ya)) or floor,
                         max(hold, floor) if math.isfinite(hold) else float(np.std(ya)) or floor,
                         len(ya))


def regression_of(cfg: PlantConfig) -> LabRegression | None:
    """The ``[regression]`` PARAMS.toml gave ``cfg`` (built once), or None."""
    return built_table(cfg, "regression",
                       lambda c: None if c.extra.get("regression") is None else
                       LabRegression.from_table(c.extra["regression"], c.source))


__all__ = ["REGRESSION_SIGNALS", "RIDGE", "LabRegression", "at_windows", "fit_lab_regression",
           "lab_features", "regression_of", "window_means"]
