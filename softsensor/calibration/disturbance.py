"""The unmeasured inlet moisture as a slow trajectory fitted with the parameters.

No instrument measures the fibre moisture entering the dryer, and it moves: from day to day
(chip species and season) and within a day. Fed the nominal value, the model's outlet
temperatures are off by about 1.7 K per 0.01 kg/kg (the evaporation load), which a calibration
of the seven parameters would otherwise absorb into the wrong parameters. So each calibration
segment carries a deviation ``d(t)`` of the inlet moisture from the nominal, piecewise linear
between knots every ``inlet_knot_hours``, with a Gaussian prior: the first knot
``~ N(0, inlet_level_std^2)`` and each step ``~ N(0, inlet_walk^2 dt)`` (a random walk).

For given parameters the model is linear enough in the inlet moisture (free water evaporates
whatever its amount; the outlet temperatures and moisture move almost proportionally over
+-0.1 kg/kg) that ``d`` is found in closed form: with the sensitivities ``s`` of every compared
output to the inlet moisture (one extra model member with the inlet moisture raised by
:data:`DELTA`), ``d = B c`` minimises the weighted least squares ``sum w (r - s B c)^2 + c' L
c`` (:func:`solve`), a ridge regression on the knot values ``c`` with the prior's precision
``L``. This is the variable-projection form of the joint fit: the parameters' cost is
measured on what is left after the best trajectory. The wall's ten-minute lag is neglected in
``s`` (knots are hours apart).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Raise of the inlet moisture in the sensitivity member [kg/kg].
DELTA = 0.02


@dataclass(frozen=True)
class InletPrior:
    """The trajectory's knots and prior (module docstring); SI units, times in hours."""

    knot_hours: float
    level_std: float
    walk: float

    def knots(self, duration_h: float) -> np.ndarray:
        """Knot times [h] from 0 to ``duration_h`` (the last knot at the end)."""
        n = max(1, int(np.ceil(duration_h / self.knot_hours - 1e-9)))
        return np.linspace(0.0, max(duration_h, 1e-9), n + 1)

    def precision(self, knots_h: np.ndarray) -> np.ndarray:
        """Prior precision ``L`` (J, J) of the knot values."""
        J = len(knots_h)
        L = np.zeros((J, J))
        L[0, 0] = 1.0 / self.level_std**2
        if J > 1:
            dt = np.diff(knots_h)
            var = np.maximum(self.walk**2 * dt, 1e-12)
            for j in range(1, J):
                w = 1.0 / var[j - 1]
                L[j - 1, j - 1] += w
                L[j, j] += w
                L[j - 1, j] -= w
                L[j, j - 1] -= w
        return L


def hat_basis(t_h: np.ndarray, knots_h: np.ndarray) -> np.ndarray:
    """Piecewise-linear interpolation weights (n, J): ``d(t) = B @ c`` for knot values ``c``
    (constant outside the knots)."""
    t = np.clip(np.asarray(t_h, float), knots_h[0], knots_h[-1])
    J = len(knots_h)
    B = np.zeros((t.size, J))
    if J == 1:
        B[:, 0] = 1.0
        return B
    j = np.clip(np.searchsorted(knots_h, t, side="right") - 1, 0, J - 2)
    f = (t - knots_h[j]) / (knots_h[j + 1] - knots_h[j])
    rows = np.arange(t.size)
    B[rows, j] = 1.0 - f
    B[rows, j + 1] = f
    return B


def solve(blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray, float]],
          precision: np.ndarray) -> np.ndarray:
    """Knot values ``c`` (J,) minimising ``sum_blocks w |r - diag(s) B c|^2 + c' L c``.

    Each block is ``(r, s, B, w)``: residuals (n,), their sensitivities to the inlet moisture
    (n,), the basis rows (n, J) and the block's weight ``1 / sigma^2``.
    """
    A = precision.copy()
    b = np.zeros(precision.shape[0])
    for r, s, B, w in blocks:
        if r.size == 0:
            continue
        M = s[:, None] * B
        A += w * (M.T @ M)
        b += w * (M.T @ r)
    return np.linalg.solve(A, b)


__all__ = ["DELTA", "InletPrior", "hat_basis", "solve"]
