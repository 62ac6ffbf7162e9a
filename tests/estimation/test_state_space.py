"""The filter's state space outside the filter itself (``softsensor/estimation/state_space.py``),
each part against a property it must have: the error processes' noise keeps their prior, the
random walks grow by their walk, the inlet walk reverts to its mean, the heat-input prior
scales with the gain, the inlet transform clips smoothly, the adaptive noise integrates the
normalised innovations. The filter's own tests (``tests/estimation/test_ukf*.py``) drive these
through the UKF; here each is pinned on its own so that a changed sign or factor shows
(``tests/support/mutation_check.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softsensor.estimation.settings import estimator_settings
from softsensor.estimation.state_space import (
    AdaptiveNoise,
    ErrorPriors,
    InletTransform,
    process_noise,
    transition,
)

PRIORS = ErrorPriors(sigma=np.array([0.5, 1.0, 2.0, 0.01, 0.8]),
                     tau=np.array([6.0, 12.0, 24.0, 48.0, 36.0]) * 3600.0, source="test")
#: The same with the last two states random walks (a history's channel offsets; the gain).
WALKS = ErrorPriors(sigma=PRIORS.sigma, tau=np.r_[PRIORS.tau[:3], np.inf, np.inf],
                    source="test", walk=np.array([0.0, 0.0, 0.0, 2e-5, 1e-3]))


@pytest.mark.parametrize("window_s", [60.0, 600.0, 7200.0])
def test_error_states_keep_their_prior_variance_over_any_window(window_s):
    # P = F P F + Q with P = diag(sigma^2): an Ornstein-Uhlenbeck process discretised exactly
    F = transition(window_s, PRIORS, inlet_tau_s=48 * 3600.0)
    Q = np.diag(process_noise(window_s, PRIORS, walk_s=0.01, inlet_tau_s=48 * 3600.0))
    P = np.diag(PRIORS.sigma**2)
    np.testing.assert_allclose((F[1:, 1:] @ P @ F[1:, 1:] + Q[1:, 1:]), P, rtol=1e-12)
    assert F[1, 1] == pytest.approx(math.exp(-window_s / PRIORS.tau[0]), rel=1e-12)


@pytest.mark.parametrize("window_s", [60.0, 600.0, 7200.0])
def test_random_walk_error_states_grow_by_their_walk_and_do_not_decay(window_s):
    F = transition(window_s, WALKS, inlet_tau_s=48 * 3600.0)
    Q = process_noise(window_s, WALKS, walk_s=0.01, inlet_tau_s=48 * 3600.0)
    np.testing.assert_array_equal(np.diag(F)[-2:], [1.0, 1.0])
    np.testing.assert_allclose(Q[-2:], WALKS.walk[-2:] ** 2 * window_s, rtol=1e-12)
    # the first-order states are unchanged by their neighbours being walks
    np.testing.assert_allclose(Q[1:4], PRIORS.sigma[:3] ** 2
                               * (1 - np.exp(-2 * window_s / PRIORS.tau[:3])), rtol=1e-12)


def test_inlet_walk_is_mean_reverting_with_the_walks_short_term_variance():
    window_s, tau, walk = 600.0, 48 * 3600.0, 0.02
    F = transition(window_s, PRIORS, inlet_tau_s=tau)
    Q = np.diag(process_noise(window_s, PRIORS, walk_s=walk, inlet_tau_s=tau))
    assert F[0, 0] == pytest.approx(math.exp(-window_s / tau), rel=1e-12)
    # a window much shorter than tau: a random walk of walk^2 per window
    assert Q[0, 0] == pytest.approx(walk**2, rel=window_s / tau)
    # the stationary variance of the discretised process equals the continuous one,
    # walk^2 tau / (2 window)
    assert Q[0, 0] / (1.0 - F[0, 0] ** 2) == pytest.approx(walk**2 * tau / (2 * window_s),
                                                           rel=1e-12)


def test_heat_input_prior_is_the_common_temperature_error_over_the_gain(config):
    s = estimator_settings(config)
    one = ErrorPriors.from_config(config, s, heat_gain=1.0)
    half = ErrorPriors.from_config(config, s, heat_gain=0.5)
    # a heat input that moves the outlets half as much must err twice as far
    assert half.sigma[0] == pytest.approx(2.0 * one.sigma[0], rel=1e-12)
    np.testing.assert_array_equal(half.sigma[1:], one.sigma[1:])


def test_inlet_transform_is_the_identity_inside_and_a_smooth_clip_outside():
    t = InletTransform(lo=0.5, hi=1.5, margin=0.1)
    inside = np.linspace(0.61, 1.39, 9)
    np.testing.assert_array_equal(t.forward(inside), inside)
    s = np.linspace(-2.0, 4.0, 601)
    x = t.forward(s)
    assert np.all((x > 0.5) & (x < 1.5)) and np.all(np.diff(x) > 0)
    near = np.abs(s - 1.0) <= 0.8  # four margins out: the clip still resolves its input
    np.testing.assert_allclose(t.inverse(x[near]), s[near], rtol=0, atol=1e-9)
    h = 1e-6
    fd = (t.forward(s + h) - t.forward(s - h)) / (2 * h)
    np.testing.assert_allclose(t.derivative(s), fd, rtol=0, atol=1e-5)  # h at the joints


def test_adaptive_noise_integrates_the_normalised_innovations():
    a = AdaptiveNoise.fresh()
    a.update(0, 1.0, 10, 25.0)  # consistent: no change
    assert a.factor[0] == 1.0
    a.update(0, 4.0, 10, 25.0)  # three above one, over ten ticks of memory
    assert a.factor[0] == pytest.approx(1.3)
    a.update(0, 1e6, 10, 25.0)  # one outlier counts at most nine
    assert a.factor[0] == pytest.approx(1.3 * 1.8)
    for _ in range(100):
        a.update(0, 0.0, 10, 25.0)
    assert a.factor[0] == 1.0  # never below one
    for _ in range(100):
        a.update(1, 9.0, 10, 25.0)
    assert a.factor[1] == 25.0  # never above the limit
    a.factor[:] = [2.0, 3.0, 4.0]
    np.testing.assert_array_equal(a.inflation(), [2.0, 2.0, 3.0, 4.0, 4.0])


def test_the_inlet_gain_response_is_never_inverted_and_is_the_identity_near_one():
    """``1 + inlet_gain`` bounded below (issue 47: a sigma point reached -1.65): never
    under the floor however far out, unchanged within 1e-6 while the response is above 0.7."""
    from softsensor.estimation.state_space import GAIN_RESPONSE_FLOOR, gain_response

    g = np.linspace(-10.0, 3.0, 2001)
    r = gain_response(g)
    assert np.all(r >= GAIN_RESPONSE_FLOOR) and np.all(np.diff(r) >= 0)
    near = g[g > -0.3]
    assert np.allclose(gain_response(near), 1.0 + near, atol=1e-6, rtol=0)
    assert gain_response(-2.65) < 0.06  # the reported sigma point: a dryer at equilibrium
