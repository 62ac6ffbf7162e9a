"""What each cause would leave on this day: its signature at a plant's size, seen by the normal.

Beside the verdict, every cause of :data:`~.extensions.EXTENSIONS` is applied to the
baseline at its :attr:`~.extensions.Extension.probe_size` (the virtual plant's default size
of the effect) over the whole day (:meth:`~.extensions.Extension.probe`), and the change of
the residuals is whitened through the calibration-error alternative exactly as the scores are
(:meth:`Problem.whitened <softsensor.diagnosis.problem.Problem.whitened>`, whole day). The
whitening is linear, so that change, the *signature* ``d``, is what the normal cannot
predict of the cause on this day: a lab delay on a day whose outlet moisture hardly moves,
or an ambient heat loss on a mild day, leaves a short signature, and a constant offset is
mostly taken up by the slow states of the normal after a few hours.

* **Detectable size**: a cause of size ``x`` (signature ``d x / probe``) fitted exactly
  gains ``|d|^2 (x / probe)^2 / 2`` nats, less one per parameter; it reaches the verdict's
  ``MIN_PENALISED`` at ``x = probe sqrt(2 (MIN_PENALISED + k)) / |d|``. A cause smaller than
  that cannot be named on this day, whatever the fit (cross-fitting and the eq. 4 gain ask
  a little more).
* **Collinearity** of two causes: ``|cos|`` of the angle between their signatures. Near 1,
  both leave the same trace on this day, and which one it was cannot be told from the data
  (:func:`softsensor.diagnosis.posterior.cannot_tell`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from softsensor.diagnosis.extensions import Extension, Fitted
from softsensor.diagnosis.problem import Problem
from softsensor.diagnosis.verdict import MIN_PENALISED
from softsensor.errors import SoftsensorError


@dataclass(frozen=True)
class Signature:
    """One cause's whitened signature on the day at its probe size (module docstring)."""

    cause: str
    channel: str | None
    probe_size: float
    unit: str
    n_params: int
    vector: np.ndarray

    @property
    def norm(self) -> float:
        return float(np.linalg.norm(self.vector))

    @property
    def detectable_size(self) -> float:
        """The smallest size [``unit``] the verdict can name on this day (inf: none)."""
        n = self.norm
        if not n > 0:
            return math.inf
        return self.probe_size * math.sqrt(2.0 * (MIN_PENALISED + self.n_params)) / n

    def to_json(self) -> dict[str, object]:
        det = self.detectable_size
        return {"cause": self.cause, "channel": self.channel, "probe_size": self.probe_size,
                "unit": self.unit, "loglik_at_probe": round(0.5 * self.norm ** 2, 3),
                "detectable_size": float(det) if math.isfinite(det) else None}


def signature(problem: Problem, ext: Extension, channel: str | None = None) -> Signature:
    """``ext``'s signature on ``problem``'s day (module docstring); a probe the model cannot
    run leaves an empty signature (the cause is not detectable there)."""
    channel = channel or ext.default_channel
    base = problem.whitened(problem.baseline, "all")
    try:
        probe = problem.whitened(ext.probe(problem, channel), "all")
    except SoftsensorError:
        probe = base
    parts = [b - p if b.shape == p.shape else np.zeros_like(b)
             for b, p in zip(base, probe, strict=True)]
    return Signature(ext.cause, channel, float(ext.probe_size), ext.probe_unit, ext.n_params,
                     np.concatenate(parts))


def signatures(problem: Problem, extensions: Iterable[Extension],
               fitted: dict[str, Fitted]) -> dict[str, Signature]:
    """Every cause's signature; a sensor offset on the channel its fit chose (the dryer
    outlet when it was not fitted)."""
    out = {}
    for ext in extensions:
        f = fitted.get(ext.cause)
        out[ext.cause] = signature(problem, ext, f.channel if f is not None else None)
    return out


def collinearity(a: Signature, b: Signature) -> float:
    """``|cos|`` of the angle between two signatures (0 when either is empty)."""
    na, nb = a.norm, b.norm
    if not (na > 0 and nb > 0):
        return 0.0
    return abs(float(a.vector @ b.vector)) / (na * nb)
