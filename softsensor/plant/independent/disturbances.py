"""The day's true disturbances of the independent plant, drawn from the day seed.

Everything a real dryer meets and the soft sensor does not measure, or measures as an
input: production changes (levels from the ``[virtual_plant]`` range, held for hours, joined
by raised-cosine transitions of 10 to 25 min), occasional set-point moves typed in by the
operator, a daily ambient cycle (coldest near 5 h, warmest near 15 h) with weather drift,
relative humidity falling as the day warms, wind (log-normal, gusting on a 20 min scale
around a slowly drifting mean) and cloud cover, fan flow wander, fibre temperature and steam
wander, the burner gas (temperature swings with burner load, humidity with the fuel's
moisture), and the inlet fibre moisture: a day-level mean around the nominal (standard
deviation drawn per plant, clipped to 0.9..1.1 kg/kg) plus a slow within-day wander.

The slow processes are Ornstein-Uhlenbeck, sampled exactly:
``x_k = a x_(k-1) + sqrt(1 - a^2) w_k``, ``a = exp(-dt / tau)`` (Gillespie 1996, *Phys. Rev.
E* 54:2084, eq. 1.3), with unit stationary variance, scaled where used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from softsensor.plant.independent.family import Structure
from softsensor.plant.independent.properties import M_AIR, humidity_from_vapour_pressure, p_sat
from softsensor.plant.settings import VirtualPlantSettings
from softsensor.plantconfig import PlantConfig


@dataclass(frozen=True)
class Day:
    """True disturbances per plant step (arrays of length ``n``), ``t`` [s] from the start."""

    t: np.ndarray
    m_fiber: np.ndarray       # kg/s dry
    moisture_in: np.ndarray   # kg/kg
    T_fiber_in: np.ndarray    # K
    m_steam: np.ndarray       # kg/s
    m_air: np.ndarray         # kg/s dry gas (fan)
    T_sp: np.ndarray          # K
    T_amb: np.ndarray         # K
    H_amb: np.ndarray         # kg/kg
    wind: np.ndarray          # m/s
    cloud: np.ndarray         # -
    T_hot: np.ndarray         # K
    Y_hot: np.ndarray         # kg/kg


@dataclass(frozen=True)
class UnmeasuredFlow:
    """A surge of the fan's flow its meter does not see: the true gas flow is the day's times
    ``1 + amplitude sin(2 pi t / period_s + phase)`` (a damper hunting, a leaking inspection
    door, a fan whose speed loop oscillates) while the recorded ``m_air`` keeps the day's own.
    ``amplitude`` [-] relative, ``period_s`` [s], ``phase`` [rad]."""

    amplitude: float
    period_s: float
    phase: float = 0.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.amplitude < 0.5 and self.period_s > 0.0):
            raise ValueError(f"unmeasured flow: amplitude in [0, 0.5) and period > 0 s, got "
                             f"{self.amplitude!r}, {self.period_s!r}")

    def applied(self, t: np.ndarray, m_air: np.ndarray) -> np.ndarray:
        """The true gas flow [kg/s] at times ``t`` [s] given the day's ``m_air`` [kg/s]."""
        return m_air * (1.0 + self.amplitude * np.sin(2.0 * np.pi * t / self.period_s
                                                      + self.phase))


def ou(rng: np.random.Generator, n: int, dt: float, tau: float) -> np.ndarray:
    """Unit-variance Ornstein-Uhlenbeck path of ``n`` samples ``dt`` [s] apart, time
    constant ``tau`` [s], started from its stationary distribution."""
    a = np.exp(-dt / tau)
    w = rng.standard_normal(n)
    w[1:] *= np.sqrt(1.0 - a * a)
    x, _ = lfilter([1.0], [1.0, -a], w[1:], zi=[a * w[0]])
    return np.concatenate([[w[0]], x])


def smooth_ou(rng: np.random.Generator, n: int, dt: float, tau: float, tau_s: float
              ) -> np.ndarray:
    """Ornstein-Uhlenbeck path passed through a first-order lag of ``tau_s`` [s] (the inertia
    of what carries it: a burner chamber, a plug screw), rescaled to unit variance."""
    x = ou(rng, n, dt, tau)
    a = np.exp(-dt / tau_s)
    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return y * np.sqrt((tau + tau_s) / tau)


def _raised_cosine(t: np.ndarray, t0: float, width: float) -> np.ndarray:
    """0 before ``t0``, 1 after ``t0 + width``, a half cosine in between."""
    x = np.clip((t - t0) / width, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _production(rng: np.random.Generator, t: np.ndarray, s: VirtualPlantSettings
                ) -> tuple[np.ndarray, list[float]]:
    level = rng.uniform(s.m_fiber_min, s.m_fiber_max)
    m = np.full(t.shape, level)
    changes = []
    tc = rng.uniform(0.3, 1.0) * s.production_hold_min
    while tc < t[-1]:
        new = rng.uniform(s.m_fiber_min, s.m_fiber_max)
        m += (new - level) * _raised_cosine(t, tc, rng.uniform(600.0, 1500.0))
        changes.append(tc)
        level = new
        tc += rng.uniform(s.production_hold_min, s.production_hold_max)
    return m, changes


def draw_day(config: PlantConfig, s: VirtualPlantSettings, structure: Structure,
             hours: float, dt: float, rng: np.random.Generator) -> Day:
    """Draw a day's disturbances on the plant-step grid (no effect applied)."""
    n = int(round(hours * 3600.0 / dt)) + 1
    t = np.arange(n) * dt
    nom = config.nominal
    st = structure

    m_fiber, changes = _production(rng, t, s)
    m_fiber *= 1.0 + 0.004 * smooth_ou(rng, n, dt, 300.0, 60.0)

    # set point: the operator moves it now and then with a production change, never in
    # the first hour
    T_sp = np.full(n, nom.T_sp)
    for tc in changes:
        if tc > 3600.0 and rng.random() < s.setpoint_change_probability:
            T_sp[t >= tc] = float(np.clip(nom.T_sp + rng.uniform(-2.0, 2.0), 344.0, 352.0))

    # ambient: asymmetric daily cycle plus weather drift
    mean = rng.uniform(s.ambient_mean_min, s.ambient_mean_max)
    amp = rng.uniform(s.ambient_amplitude_min, s.ambient_amplitude_max)
    hour = (t / 3600.0 + rng.uniform(0.0, 24.0)) % 24.0
    cycle = (np.cos(2 * np.pi * (hour - 15.0) / 24.0)
             + 0.25 * np.cos(4 * np.pi * (hour - 15.0) / 24.0 + 0.6)) / 1.1
    T_amb = np.clip(mean + amp * cycle + 1.5 * ou(rng, n, dt, 6 * 3600.0), 256.0, 309.0)
    rh = np.clip(rng.uniform(0.55, 0.85) + 0.08 * ou(rng, n, dt, 5 * 3600.0) - 0.12 * cycle,
                 0.25, 0.97)
    pv = rh * np.array([p_sat(x) for x in T_amb])
    H_amb = np.clip(humidity_from_vapour_pressure(pv, M_AIR, config.environment.pressure),
                    0.0012, 0.019)
    wind_day = st.wind_median * np.exp(0.35 * rng.standard_normal())
    wind = wind_day * np.exp(0.3 * ou(rng, n, dt, 3 * 3600.0)
                             + 0.25 * smooth_ou(rng, n, dt, 1200.0, 60.0))
    cloud = 1.0 / (1.0 + np.exp(-(rng.normal(0.0, 1.0) + 1.5 * ou(rng, n, dt, 4 * 3600.0))))

    m_air = nom.m_air * (1.0 + np.clip(0.025 * ou(rng, n, dt, 2 * 3600.0), -0.08, 0.08))
    T_fiber_in = np.clip(nom.T_fiber_in + 1.5 * ou(rng, n, dt, 5400.0)
                         + 0.4 * smooth_ou(rng, n, dt, 300.0, 60.0), nom.T_fiber_in - 8.0, 372.0)
    m_steam = nom.m_steam * np.clip(1.0 + 0.08 * ou(rng, n, dt, 3600.0), 0.6, 1.4)

    T_hot = st.T_hot + 12.0 * smooth_ou(rng, n, dt, 2400.0, 180.0)
    Y_hot = st.Y_hot * (1.0 + 0.08 * rng.standard_normal()) \
        * (1.0 + 0.1 * ou(rng, n, dt, 3 * 3600.0))

    day_mean = float(np.clip(nom.moisture_in + st.moisture_day_sd * rng.standard_normal(),
                             0.9, 1.1))
    moisture_in = day_mean + st.moisture_wander_sd * ou(rng, n, dt, st.moisture_wander_tau)
    return Day(t, m_fiber, moisture_in, T_fiber_in, m_steam, m_air, T_sp, T_amb, H_amb,
               wind, cloud, T_hot, Y_hot)
