"""Heat- and mass-transfer coefficients and the fibre slip velocity, SI units, vectorised.

Written with numpy arithmetic only, so that :mod:`softsensor.model.kernels` can compile the
same source with numba. Correlations: a cylinder in cross flow [1]_, natural convection from a
horizontal cylinder [2]_, turbulent pipe flow [3]_, the Chilton-Colburn analogy [4]_ and the
standard drag curve [5]_.

References
----------
.. [1] Churchill, S.W., Bernstein, M. (1977), J. Heat Transfer 99, 300-306: cylinder in
   cross flow, ``Nu = 0.3 + 0.62 Re^1/2 Pr^1/3 / (1 + (0.4/Pr)^2/3)^1/4 (1 + (Re/282000)^5/8)^4/5``.
.. [2] Churchill, S.W., Chu, H.H.S. (1975), Int. J. Heat Mass Transfer 18, 1049: natural
   convection from a horizontal cylinder.
.. [3] Gnielinski, V. (1976), Int. Chem. Eng. 16, 359: turbulent pipe flow.
.. [4] Chilton-Colburn analogy, the paper's eq. 1: ``K_c = h / (rho c_p) (Sc/Pr)^(-2/3)``.
   The paper prints the exponent as +2/3; the analogy (Bird et al. 2002, eq. 14.5-5) has -2/3.
.. [5] Perry & Green (1984) sect. 6 / Clift, Grace & Weber (1978): standard drag curve
   ``C_D = 24/Re (1 + 0.15 Re^0.687) + 0.42 / (1 + 42500 Re^-1.16)``.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

SIGMA = 5.670374419e-8  # W/(m2 K4), Stefan-Boltzmann
G = 9.80665  # m/s2


@register_jitable
def churchill_bernstein(Re, Pr):
    """Mean Nusselt number of a cylinder in cross flow [-], ref. [1]."""
    return 0.3 + 0.62 * np.sqrt(Re) * Pr ** (1.0 / 3.0) / (
        (1.0 + (0.4 / Pr) ** (2.0 / 3.0)) ** 0.25) * (1.0 + (Re / 282000.0) ** 0.625) ** 0.8


@register_jitable
def churchill_chu(Ra, Pr):
    """Mean Nusselt number of a horizontal cylinder in natural convection [-], ref. [2]."""
    return (0.60 + 0.387 * Ra ** (1.0 / 6.0)
            / (1.0 + (0.559 / Pr) ** (9.0 / 16.0)) ** (8.0 / 27.0)) ** 2


@register_jitable
def gnielinski(Re, Pr):
    """Nusselt number of turbulent flow in a smooth pipe [-], ref. [3] (Re > 3000)."""
    Re = np.maximum(Re, 3000.0)
    f = (0.790 * np.log(Re) - 1.64) ** -2
    return (f / 8.0) * (Re - 1000.0) * Pr / (
        1.0 + 12.7 * np.sqrt(f / 8.0) * (Pr ** (2.0 / 3.0) - 1.0))


@register_jitable
def mass_transfer_coefficient(h, rho, cp, Sc, Pr):
    """Mass-transfer coefficient ``K_c`` [m/s] from the heat-transfer coefficient ``h``.

    The paper's eq. 1 (Chilton-Colburn, ref. [4]); ``rho`` [kg/m3] and ``cp`` [J/(kg K)] of the
    moist air.
    """
    return h / (rho * cp) * (Sc / Pr) ** (-2.0 / 3.0)


@register_jitable
def drag_coefficient(Re):
    """Standard drag curve of a sphere ``C_D`` [-], ref. [5]."""
    Re = np.maximum(Re, 1e-9)
    return 24.0 / Re * (1.0 + 0.15 * Re**0.687) + 0.42 / (1.0 + 42500.0 * Re**-1.16)


@register_jitable
def slip_velocity(d_p, rho_p, rho, mu):
    """Slip (terminal settling) velocity ``v_slip`` [m/s] of a fibre in rising air.

    Force balance ``(rho_p - rho) g V = C_D(Re) rho v^2 A / 2`` on the fibre's volume-equivalent
    sphere of diameter ``d_p`` [m], solved by fixed-point iteration from the Stokes velocity
    (the paper: "slip velocity dynamics derived from standard drag expressions", ref. [5]).
    """
    v = (rho_p - rho) * G * d_p * d_p / (18.0 * mu)
    for _ in range(12):
        Re = rho * v * d_p / mu
        v = np.sqrt(4.0 * (rho_p - rho) * G * d_p / (3.0 * drag_coefficient(Re) * rho))
    return v


@register_jitable
def radiation_coefficient(T_w, T_amb, emissivity):
    """Linearised radiation coefficient ``h_rad`` [W/(m2 K)] of a grey wall to surroundings."""
    return emissivity * SIGMA * (T_w * T_w + T_amb * T_amb) * (T_w + T_amb)


@register_jitable
def outside_coefficient(T_w, T_amb, D, wind, emissivity, k, nu, Pr):
    """Wall-to-ambient coefficient ``h_out`` [W/(m2 K)] of a bare cylinder of diameter ``D``.

    Forced (Churchill-Bernstein [1], wind across the cylinder) and natural (Churchill-Chu [2])
    convection combined as ``(Nu_f^3 + Nu_n^3)^(1/3)`` (Churchill 1977), plus linearised
    radiation. Film properties ``k`` [W/(m K)], ``nu`` [m2/s], ``Pr`` [-] at ambient.
    """
    Re = np.maximum(wind, 1e-6) * D / nu
    Nu_f = churchill_bernstein(Re, Pr)
    dT = np.maximum(np.abs(T_w - T_amb), 1e-3)
    Tf = 0.5 * (T_w + T_amb)
    Ra = G * dT / Tf * D**3 / (nu * nu) * Pr
    Nu_n = churchill_chu(Ra, Pr)
    Nu = (Nu_f**3 + Nu_n**3) ** (1.0 / 3.0)
    return Nu * k / D + radiation_coefficient(T_w, T_amb, emissivity)
