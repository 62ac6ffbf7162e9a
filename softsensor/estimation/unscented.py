"""The four pieces of filterpy the filter's tick uses, without importing filterpy.

``filterpy.kalman`` imports all of filterpy's filters and, through ``filterpy.stats``,
``scipy.stats``: 45 MB of the daemon's resident memory for four small functions (issue 31
item 2). These are filterpy 1.4.5's :class:`MerweScaledSigmaPoints` (with its default
``scipy.linalg.cholesky`` square root and ``np.subtract``), ``unscented_transform`` (default
mean and residual), ``kalman.predict`` and ``kalman.update`` (``return_all=False``), the same
operations in the same order, so the numbers are bit for bit filterpy's
(``tests/estimation/test_unscented.py`` checks against filterpy itself, which stays the reference).
filterpy is MIT-licensed, copyright 2015 Roger R. Labbe Jr.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cholesky


class MerweScaledSigmaPoints:
    """Van der Merwe's scaled sigma points of ``n`` states (filterpy's class of that name)."""

    def __init__(self, n: int, alpha: float, beta: float, kappa: float) -> None:
        self.n, self.alpha, self.beta, self.kappa = n, alpha, beta, kappa
        lambda_ = alpha**2 * (n + kappa) - n
        c = .5 / (n + lambda_)
        self.Wc = np.full(2 * n + 1, c)
        self.Wm = np.full(2 * n + 1, c)
        self.Wc[0] = lambda_ / (n + lambda_) + (1 - alpha**2 + beta)
        self.Wm[0] = lambda_ / (n + lambda_)

    def num_sigmas(self) -> int:
        return 2 * self.n + 1

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """The ``2n+1`` sigma points (rows) of mean ``x`` and covariance ``P``."""
        if self.n != np.size(x):
            raise ValueError(f"expected size(x) {self.n}, but size is {np.size(x)}")
        n = self.n
        if np.isscalar(x):
            x = np.asarray([x])
        P = np.eye(n) * P if np.isscalar(P) else np.atleast_2d(P)
        lambda_ = self.alpha**2 * (n + self.kappa) - n
        U = cholesky((lambda_ + n) * P)
        sigmas = np.zeros((2 * n + 1, n))
        sigmas[0] = x
        for k in range(n):
            sigmas[k + 1] = np.subtract(x, -U[k])
            sigmas[n + k + 1] = np.subtract(x, U[k])
        return sigmas


def unscented_transform(sigmas: np.ndarray, Wm: np.ndarray, Wc: np.ndarray,
                        noise_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the weighted sigma points (rows of ``sigmas``)."""
    x = np.dot(Wm, sigmas)
    y = sigmas - x[np.newaxis, :]
    P = np.dot(y.T, np.dot(np.diag(Wc), y))
    if noise_cov is not None:
        P += noise_cov
    return x, P


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray, u=0, B=1,
            alpha: float = 1.) -> tuple[np.ndarray, np.ndarray]:
    """Kalman prediction: ``F x + B u`` and ``alpha^2 F P F' + Q``."""
    if np.isscalar(F):
        F = np.array(F)
    x = np.dot(F, x) + np.dot(B, u)
    P = (alpha * alpha) * np.dot(np.dot(F, P), F.T) + Q
    return x, P


def _reshape_z(z, dim_z: int, ndim: int) -> np.ndarray:
    """filterpy.common.reshape_z: ``z`` as a column (``ndim`` 2) or a vector."""
    z = np.atleast_2d(z)
    if z.shape[1] == dim_z:
        z = z.T
    if z.shape != (dim_z, 1):
        raise ValueError(f"z must be convertible to shape ({dim_z}, 1)")
    if ndim == 1:
        z = z[:, 0]
    if ndim == 0:
        z = z[0, 0]
    return z


def update(x: np.ndarray, P: np.ndarray, z, R: np.ndarray, H=None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with the Joseph form of the covariance (filterpy's ``update``)."""
    if z is None:
        return x, P
    if H is None:
        H = np.array([1])
    if np.isscalar(H):
        H = np.array([H])
    Hx = np.atleast_1d(np.dot(H, x))
    z = _reshape_z(z, Hx.shape[0], x.ndim)
    y = z - Hx
    S = np.dot(np.dot(H, P), H.T) + R
    try:
        K = np.dot(np.dot(P, H.T), np.linalg.inv(S))
    except (np.linalg.LinAlgError, ValueError):  # a 1-D S cannot be inverted
        K = np.dot(np.dot(P, H.T), 1. / S)
    x = x + np.dot(K, y)
    KH = np.dot(K, H)
    try:
        I_KH = np.eye(KH.shape[0]) - KH
    except (IndexError, TypeError):
        I_KH = np.array([1 - KH])
    P = np.dot(np.dot(I_KH, P), I_KH.T) + np.dot(np.dot(K, R), K.T)
    return x, P


__all__ = ["MerweScaledSigmaPoints", "predict", "unscented_transform", "update"]
