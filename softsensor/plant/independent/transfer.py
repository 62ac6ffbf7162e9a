"""Transfer correlations of the independent plant: fibre, drag, inner wall, outside surfaces.

* Fibre-gas heat and mass transfer: Ranz and Marshall (1952), ``Nu = 2 + 0.6 Re^1/2 Pr^1/3``
  and ``Sh = 2 + 0.6 Re^1/2 Sc^1/3`` on the fibre diameter and the gas-floc slip; with
  Stefan flow the conductive heat to the surface takes Ackermann's (1937) factor
  ``phi / (exp(phi) - 1)``, ``phi = N c_pv / h`` (Bird, Stewart, Lightfoot eq. 22.8-36).
* Floc drag: Haider and Levenspiel (1989), Powder Technology 58:63, eq. 10 with the
  sphericity-dependent constants ``A .. D`` (their eqs. 11 to 14).
* Gas to the tube wall: Gnielinski (1976), valid 2300 < Re < 5e6, with the friction factor of
  Petukhov ``f = (0.79 ln Re - 1.64)^-2`` and Hausen's entry term ``1 + (D / z)^(2/3)`` taken
  locally per segment (VDI Heat Atlas, 2nd ed., G1 eq. 27-28).
* Outside, per unit area: forced cross-flow over a cylinder after Zukauskas (1972) (Incropera
  et al., *Fundamentals of Heat and Mass Transfer*, 7th ed., eq. 7.53 and Table 7.4),
  natural convection after Churchill and Chu (1975) for a horizontal cylinder (eq. 9.34 of
  the same), combined as ``(Nu_f^3 + Nu_n^3)^(1/3)`` (Churchill 1977), and long-wave
  radiation to a sky at Swinbank's (1963) ``T_sky = 0.0552 T_amb^1.5`` (clear) blended with
  the ambient temperature by cloud cover, half the view to the sky and half to the ground.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from softsensor.plant.independent.properties import G_ACC, SIGMA, transport


def haider_levenspiel_constants(sphericity: float) -> np.ndarray:
    """Constants ``A, B, C, D`` of the Haider-Levenspiel drag law for a sphericity [-]."""
    s = sphericity
    return np.array([
        math.exp(2.3288 - 6.4581 * s + 2.4486 * s * s),
        0.0964 + 0.5565 * s,
        math.exp(4.905 - 13.8944 * s + 18.4222 * s * s - 10.2599 * s ** 3),
        math.exp(1.4681 + 12.2584 * s - 20.7322 * s * s + 15.8855 * s ** 3),
    ])


@njit(cache=True)
def drag_coefficient(re: float, a: float, b: float, c: float, d: float) -> float:
    """Haider-Levenspiel drag coefficient [-] at particle Reynolds number ``re``."""
    re = max(re, 1e-6)
    return 24.0 / re * (1.0 + a * re ** b) + c / (1.0 + d / re)


@njit(cache=True)
def ranz_marshall(re: float, pr_or_sc: float) -> float:
    """Nusselt or Sherwood number of a small particle (Ranz and Marshall 1952)."""
    return 2.0 + 0.6 * math.sqrt(max(re, 0.0)) * pr_or_sc ** (1.0 / 3.0)


@njit(cache=True)
def ackermann(phi: float) -> float:
    """Ackermann's correction ``phi / (exp(phi) - 1)`` of conduction under Stefan flow."""
    if abs(phi) < 1e-4:
        return 1.0 - 0.5 * phi + phi * phi / 12.0
    return phi / math.expm1(phi)


@njit(cache=True)
def gnielinski(re: float, pr: float) -> float:
    """Fully developed turbulent pipe-flow Nusselt number (Gnielinski 1976)."""
    re = max(re, 2300.0)
    f = (0.79 * math.log(re) - 1.64) ** -2
    return (f / 8.0) * (re - 1000.0) * pr / (1.0 + 12.7 * math.sqrt(f / 8.0)
                                             * (pr ** (2.0 / 3.0) - 1.0))


def entry_factor(z_mid: float, diameter: float) -> float:
    """Hausen's entry enhancement ``1 + (D/z)^(2/3)`` at ``z_mid`` [m], at most 2."""
    return 1.0 + (diameter / max(z_mid, diameter)) ** (2.0 / 3.0)


@njit(cache=True)
def sky_temperature(T_amb: float, cloud: float) -> float:
    """Effective sky temperature [K]: Swinbank's clear sky blended by cloud cover [0..1]."""
    t_clear = 0.0552 * T_amb ** 1.5
    return ((1.0 - cloud) * t_clear ** 4 + cloud * T_amb ** 4) ** 0.25


@njit(cache=True)
def outside_coefficients(T_s: float, T_amb: float, T_sky: float, wind: float,
                         diameter: float, emissivity: float) -> tuple[float, float, float]:
    """Outside heat loss of a cylinder, linearised at its surface temperature ``T_s`` [K].

    Returns ``(h_conv, h_rad, T_rad)``: convective coefficient [W/(m2 K)] to ``T_amb``, and a
    radiative coefficient [W/(m2 K)] to the mean radiant temperature ``T_rad`` [K] such that
    ``h_rad (T_s - T_rad)`` equals the exact radiative loss at ``T_s``.
    """
    T_f = 0.5 * (T_s + T_amb)
    mu, k = transport(T_f, 0.005)
    rho = 101325.0 * 0.0289647 / (8.314462618 * T_f)
    nu = mu / rho
    pr = 0.71
    re = max(wind, 0.0) * diameter / nu
    if re < 40.0:
        c, m = 0.75, 0.4
    elif re < 1000.0:
        c, m = 0.51, 0.5
    elif re < 2.0e5:
        c, m = 0.26, 0.6
    else:
        c, m = 0.076, 0.7
    nu_f = c * re ** m * pr ** 0.37
    ra = G_ACC * abs(T_s - T_amb) / T_f * diameter ** 3 / (nu * nu) * pr
    nu_n = (0.6 + 0.387 * ra ** (1.0 / 6.0)
            / (1.0 + (0.559 / pr) ** (9.0 / 16.0)) ** (8.0 / 27.0)) ** 2
    h_conv = (nu_f ** 3 + nu_n ** 3) ** (1.0 / 3.0) * k / diameter
    t4 = 0.5 * (T_sky ** 4 + T_amb ** 4)
    T_rad = t4 ** 0.25
    if abs(T_s - T_rad) < 1e-9:
        h_rad = 4.0 * emissivity * SIGMA * T_s ** 3
    else:
        h_rad = emissivity * SIGMA * (T_s ** 4 - t4) / (T_s - T_rad)
    return h_conv, h_rad, T_rad
