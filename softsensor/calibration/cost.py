"""The calibration cost: the paper's eq. 4, per channel and weighted.

    J = sum_m WF_m * sqrt( (1/N_m) * sum_k (y_real,m,k - y_model,m,k)^2 )          (eq. 4)

over the channels ``T_dryer_out`` and ``T_cyclone_out`` [K] (window means, one sample per
window with enough good scans) and ``moisture_out`` [kg/kg] (lab samples, the model
interpolated to each sample's *sample* time). The weights ``WF_m`` come from the config's
``[cost]`` table (0.003 per kelvin channel, 5.0 for moisture, as in the paper).

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


def model_at_labs(Y_model: np.ndarray, seg: Segment) -> np.ndarray:
    """Model ``moisture_out`` at the lab sample times [kg/kg].

    ``Y_model`` has shape ``(..., K, 3)``: outputs at the end of each window. Linear
    interpolation between window ends; a sample inside the first window takes the first
    window's value.
    """
    Y_model = np.asarray(Y_model)
    pos = seg.lab_position()
    k = np.arange(Y_model.shape[-2], dtype=float)
    m = Y_model[..., 2]
    if m.ndim == 1:
        return np.interp(pos, k, m)
    flat = m.reshape(-1, m.shape[-1])
    out = np.stack([np.interp(pos, k, row) for row in flat])
    return out.reshape(m.shape[:-1] + (len(pos),))


def residuals(Y_model: np.ndarray, seg: Segment, upto: int | None = None
              ) -> list[np.ndarray]:
    """Measured minus model, per channel, over the first ``upto`` windows (default all).

    Returns three arrays (``T_dryer_out``, ``T_cyclone_out`` window residuals [K], and
    ``moisture_out`` lab residuals [kg/kg]), each of shape ``(..., n_m)``, where ``Y_model``
    of shape ``(..., K', 3)`` holds at least ``upto`` windows. Windows without a measurement
    are left out.
    """
    Y_model = np.asarray(Y_model)
    k = seg.n_windows if upto is None else int(upto)
    out = []
    for c in range(2):
        meas = seg.Y[:k, c]
        ok = np.isfinite(meas)
        out.append(meas[ok] - Y_model[..., :k, c][..., ok])
    n_lab = seg.labs_before(k)
    if n_lab == 0:
        out.append(np.zeros(Y_model.shape[:-2] + (0,)))
    else:
        pos = seg.lab_position()[:n_lab]
        kk = np.arange(k, dtype=float)
        m = Y_model[..., :k, 2]
        flat = m.reshape(-1, k)
        at = np.stack([np.interp(pos, kk, row) for row in flat]).reshape(m.shape[:-1] + (n_lab,))
        out.append(seg.lab_value[:n_lab] - at)
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


def evaluate_fit(Y_models: Sequence[np.ndarray], segments: Sequence[Segment],
                 weights: np.ndarray, upto: Sequence[int] | None = None) -> list[Fit]:
    """Eq. 4 for model outputs ``Y_models[s]`` of shape ``(B, K_s, 3)`` (or ``(K_s, 3)``).

    ``upto[s]`` limits segment ``s`` to its first windows (partial cost for pruning).
    """
    res = []
    for s, (Y, seg) in enumerate(zip(Y_models, segments, strict=True)):
        Y = np.asarray(Y)
        if Y.ndim == 2:
            Y = Y[None]
        res.append(residuals(Y, seg, None if upto is None else upto[s]))
    return fit_from_residuals(res, np.asarray(weights, float))


__all__ = ["Fit", "evaluate_fit", "fit_from_residuals", "model_at_labs", "residuals",
           "weighted_rmse"]
