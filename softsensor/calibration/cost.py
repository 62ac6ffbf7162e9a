"""The calibration cost: the paper's eq. 4, per channel and weighted.

    J = sum_m WF_m * sqrt( (1/N_m) * sum_k (y_real,m,k - y_model,m,k)^2 )          (eq. 4)

over the channels ``T_dryer_out`` and ``T_cyclone_out`` [K] (window means, one sample per
window with enough good scans) and ``moisture_out`` [kg/kg] (lab samples, the model
evaluated at each sample's *sample* time, see :mod:`.dataset`). The weights ``WF_m`` come
from the config's ``[cost]`` table (0.003 per kelvin channel, 5.0 for moisture, as in the paper).

Several segments (days or selected windows) pool their samples per channel before the root
mean square, so a channel's RMSE is over all its samples. A *partial* cost over the first
``k`` windows of every segment (the windows simulated so far) drives the pruning of hopeless
trials: it is eq. 4 on the samples available up to there.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from softsensor.calibration.dataset import Segment
from softsensor.signals import OUTPUT_NAMES


@dataclass(frozen=True)
class Fit:
    """How well model outputs match the measurements.

    Attributes
    ----------
    rmse : dict[str, float]
        Per channel, in its unit (K for temperatures, kg/kg for ``moisture_out``); NaN for a
        channel without samples.
    n : dict[str, int]
        Samples per channel.
    cost : float
        Eq. 4: ``sum_m WF_m * rmse_m`` over the channels with samples; ``inf`` when the model
        failed (NaN outputs) on any compared sample.
    """

    rmse: dict[str, float]
    n: dict[str, int]
    cost: float

    def as_dict(self) -> dict[str, object]:
        return {"rmse": dict(self.rmse), "n": dict(self.n), "cost": self.cost}


def weighted_rmse(fit: Fit, weights: np.ndarray) -> dict[str, float]:
    """``WF_m * rmse_m`` per channel (the paper quotes these, e.g. 0.04 for ~13 K)."""
    return {name: float(w * fit.rmse[name]) for name, w in zip(OUTPUT_NAMES, weights,
                                                               strict=True)}


@dataclass(frozen=True)
class ModelRun:
    """Model outputs on one segment for a batch of parameter sets.

    Attributes
    ----------
    Y : ndarray, shape (B, K, 3)
        Outputs at the end of each window.
    lab : ndarray, shape (B, L)
        ``moisture_out`` at each lab sample time [kg/kg] (see :mod:`.dataset`).
    """

    Y: np.ndarray
    lab: np.ndarray

    @classmethod
    def single(cls, Y: np.ndarray, lab: np.ndarray) -> ModelRun:
        """A run of one parameter set: ``Y`` (K, 3), ``lab`` (L,)."""
        return cls(np.asarray(Y)[None], np.asarray(lab)[None])

    def member(self, b: int | np.ndarray) -> ModelRun:
        """Batch member(s) ``b`` (an int keeps a batch axis of one)."""
        idx = np.atleast_1d(b)
        return ModelRun(self.Y[idx], self.lab[idx])

    @property
    def failed(self) -> np.ndarray:
        """(B,) True where the solve failed (NaN outputs)."""
        return np.isnan(self.Y).any(axis=(1, 2)) | np.isnan(self.lab).any(axis=1)


def residuals(run: ModelRun, seg: Segment, upto: int | None = None) -> list[np.ndarray]:
    """Measured minus model, per channel, over the first ``upto`` windows (default all).

    Returns three arrays of shape ``(B, n_m)``: ``T_dryer_out`` and ``T_cyclone_out`` window
    residuals [K] (windows without a measurement left out) and ``moisture_out`` lab
    residuals [kg/kg] for the samples taken by the end of window ``upto - 1``.
    """
    k = seg.n_windows if upto is None else int(upto)
    out = []
    for c in range(2):
        meas = seg.Y[:k, c]
        ok = np.isfinite(meas)
        out.append(meas[ok] - run.Y[:, :k, c][:, ok])
    n_lab = seg.labs_before(k)
    out.append(seg.lab_value[:n_lab] - run.lab[:, :n_lab])
    return out


def fit_from_residuals(res: Sequence[Sequence[np.ndarray]], weights: np.ndarray) -> list[Fit]:
    """Eq. 4 for a batch: ``res[s][c]`` are residuals of segment ``s``, channel ``c``, each
    of shape ``(B, n)``; returns one :class:`Fit` per batch member."""
    pooled = [np.concatenate([r[c] for r in res], axis=-1) for c in range(len(OUTPUT_NAMES))]
    B = pooled[0].shape[0]
    fits = []
    for b in range(B):
        rmse, n, cost = {}, {}, 0.0
        for c, name in enumerate(OUTPUT_NAMES):
            r = pooled[c][b]
            n[name] = int(r.size)
            if r.size == 0:
                rmse[name] = float("nan")
                continue
            value = float(np.sqrt(np.mean(r * r)))
            rmse[name] = value
            cost += float(weights[c]) * value
        if not np.isfinite(cost):
            cost = float("inf")
        fits.append(Fit(rmse=rmse, n=n, cost=cost))
    return fits


def evaluate_fit(runs: Sequence[ModelRun], segments: Sequence[Segment],
                 weights: np.ndarray, upto: Sequence[int] | None = None) -> list[Fit]:
    """Eq. 4 for every batch member of ``runs[s]`` (one per segment).

    ``upto[s]`` limits segment ``s`` to its first windows (partial cost for pruning).
    """
    res = [residuals(run, seg, None if upto is None else upto[s])
           for s, (run, seg) in enumerate(zip(runs, segments, strict=True))]
    return fit_from_residuals(res, np.asarray(weights, float))


__all__ = ["Fit", "ModelRun", "evaluate_fit", "fit_from_residuals", "residuals",
           "weighted_rmse"]
