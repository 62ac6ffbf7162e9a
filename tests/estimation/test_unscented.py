"""The filter's own copy of filterpy's sigma points, unscented transform, predict and update
(:mod:`softsensor.estimation.unscented`, which keeps ``scipy.stats`` out of the daemon) gives
filterpy's numbers bit for bit; filterpy stays the reference."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints as RefPoints
from filterpy.kalman import predict as ref_predict
from filterpy.kalman import unscented_transform as ref_ut
from filterpy.kalman import update as ref_update

from softsensor.estimation import unscented as ours


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.diag(rng.uniform(0.1, 2.0, n))


@pytest.mark.parametrize("seed", range(20))
def test_same_bits_as_filterpy(seed: int):
    rng = np.random.default_rng(seed)
    n = 7
    alpha, beta, kappa = rng.uniform(0.1, 1.0), 2.0, rng.uniform(-4.0, 3.0)
    ref, own = RefPoints(n, alpha, beta, kappa), ours.MerweScaledSigmaPoints(n, alpha, beta, kappa)
    assert np.array_equal(ref.Wm, own.Wm) and np.array_equal(ref.Wc, own.Wc)
    x, P = rng.normal(size=n), _spd(rng, n)
    sig = own.sigma_points(x, P)
    assert np.array_equal(ref.sigma_points(x, P), sig)
    y = np.tanh(sig[:, :3]) * rng.uniform(1, 5, 3)  # a nonlinear map to 3 outputs
    R = np.diag(rng.uniform(0.01, 1.0, 3))
    for a, b in zip(ref_ut(y, ref.Wm, ref.Wc, R), ours.unscented_transform(y, own.Wm, own.Wc, R),
                    strict=True):
        assert np.array_equal(a, b)
    F, Q, u = np.diag(rng.uniform(0.5, 1.0, n)), np.diag(rng.uniform(0, 0.1, n)), x * 0.3
    B = np.eye(n) - F
    for a, b in zip(ref_predict(x, P, F, Q, u=u, B=B), ours.predict(x, P, F, Q, u=u, B=B),
                    strict=True):
        assert np.array_equal(a, b)
    k = 1 + seed % 3  # one to three measured rows
    H = np.zeros((k, n))
    H[np.arange(k), rng.choice(n, k, replace=False)] = 1.0
    z, Rk = rng.normal(size=k), np.diag(rng.uniform(0.01, 1.0, k))
    for a, b in zip(ref_update(x, P, z, Rk, H), ours.update(x, P, z, Rk, H), strict=True):
        assert np.array_equal(a, b)
