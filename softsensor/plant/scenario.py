"""Disturbance trajectories of a virtual-plant day: production, set point, ambient, utilities.

Everything is drawn from one seeded generator at the control period, so a seed fixes the day.
Shapes follow what a dryer sees: production changes held for hours with 15-minute ramps,
occasional set-point moves, a daily ambient cycle, slow wander of fan flow, fibre temperature
and steam (Ornstein-Uhlenbeck, time constant about two hours).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softsensor.model import humid_air as ha
from softsensor.plant.settings import VirtualPlantSettings
from softsensor.plantconfig import PlantConfig


@dataclass(frozen=True)
class Scenario:
    """Per-control-step true inputs (arrays of length ``n``), times in s from the start."""

    t: np.ndarray
    m_fiber: np.ndarray
    T_sp: np.ndarray
    T_amb: np.ndarray
    H_amb: np.ndarray
    m_air: np.ndarray
    T_fiber_in: np.ndarray
    m_steam: np.ndarray
    moisture_in: np.ndarray


def ornstein_uhlenbeck(rng: np.random.Generator, n: int, dt: float, tau: float) -> np.ndarray:
    """Unit-variance OU process sampled every ``dt`` s with correlation time ``tau`` s."""
    a = np.exp(-dt / tau)
    e = rng.standard_normal(n) * np.sqrt(1.0 - a * a)
    x = np.empty(n)
    x[0] = rng.standard_normal()
    for i in range(1, n):
        x[i] = a * x[i - 1] + e[i]
    return x


def _ramped_levels(rng, t, hold_min, hold_max, draw, ramp=900.0):
    """Piecewise-constant levels held ``hold_min..hold_max`` s, joined by linear ramps."""
    knots_t, knots_v = [0.0], [draw()]
    while knots_t[-1] < t[-1]:
        t_change = knots_t[-1] + rng.uniform(hold_min, hold_max)
        knots_t += [t_change, t_change + ramp]
        knots_v += [knots_v[-1], draw()]
    return np.interp(t, knots_t, knots_v)


def make_scenario(cfg: PlantConfig, s: VirtualPlantSettings, hours: float,
                  rng: np.random.Generator) -> Scenario:
    """Draw a day's disturbances (no effect applied yet)."""
    dt = s.control_period
    n = int(round(hours * 3600.0 / dt)) + 1
    t = np.arange(n) * dt
    nom = cfg.nominal
    m_fiber = _ramped_levels(rng, t, s.production_hold_min, s.production_hold_max,
                             lambda: rng.uniform(s.m_fiber_min, s.m_fiber_max))
    m_fiber *= 1.0 + 0.005 * ornstein_uhlenbeck(rng, n, dt, 600.0)

    def sp_level(state=[nom.T_sp]):  # noqa: B006 - running level across draws
        if rng.random() < s.setpoint_change_probability:
            state[0] = float(np.clip(nom.T_sp + rng.uniform(-1.5, 1.5), 344.0, 352.0))
        return state[0]

    T_sp = _ramped_levels(rng, t, 6 * 3600.0, 14 * 3600.0, sp_level, ramp=60.0)
    T_sp[t < 3600.0] = nom.T_sp
    mean = rng.uniform(s.ambient_mean_min, s.ambient_mean_max)
    amp = rng.uniform(s.ambient_amplitude_min, s.ambient_amplitude_max)
    phase = rng.uniform(0, 24)  # hour of the day the record starts
    hour = (t / 3600.0 + phase) % 24.0
    T_amb = mean + amp * np.cos(2 * np.pi * (hour - 15.0) / 24.0) \
        + 1.0 * ornstein_uhlenbeck(rng, n, dt, 3 * 3600.0)
    T_amb = np.clip(T_amb, 256.0, 309.0)
    rh = np.clip(0.7 + 0.12 * ornstein_uhlenbeck(rng, n, dt, 4 * 3600.0)
                 - 0.15 * np.cos(2 * np.pi * (hour - 15.0) / 24.0), 0.3, 0.95)
    H_amb = np.clip(ha.humidity_ratio(rh * ha.p_sat(T_amb), cfg.environment.pressure),
                    0.0012, 0.019)
    m_air = nom.m_air * (1.0 + np.clip(0.03 * ornstein_uhlenbeck(rng, n, dt, 2 * 3600.0),
                                       -0.09, 0.09))
    T_fiber_in = nom.T_fiber_in + 2.0 * ornstein_uhlenbeck(rng, n, dt, 2 * 3600.0)
    m_steam = np.maximum(nom.m_steam * (1.0 + 0.08 * ornstein_uhlenbeck(rng, n, dt, 3600.0)),
                         0.0)
    moisture_in = np.full(n, nom.moisture_in)
    return Scenario(t, m_fiber, T_sp, T_amb, H_amb, m_air, T_fiber_in, m_steam, moisture_in)


def inlet_moisture_trajectory(rng: np.random.Generator, t: np.ndarray, nominal: float,
                              magnitude: float) -> np.ndarray:
    """Inlet moisture with a step and a slow drift (effect ``inlet_moisture``).

    The step is ``0.7 * magnitude`` and the drift (a slow sine) ``0.3 * magnitude``, so the
    peak deviation from nominal is ``magnitude`` at most; clipped to the range seen on the
    plant (0.8 to 1.3 kg/kg).
    """
    T = t[-1]
    sign = rng.choice([-1.0, 1.0])
    t_step = rng.uniform(0.2, 0.5) * T
    step = np.where(t >= t_step, sign * 0.7 * magnitude, 0.0)
    drift = 0.3 * magnitude * np.sin(2 * np.pi * (t / max(T, 1.0)) * rng.uniform(0.7, 1.5)
                                     + rng.uniform(0, 2 * np.pi))
    return np.clip(nominal + step + drift, 0.8, 1.3)
