"""Wood fibre: sorption isotherm, heat of sorption, enthalpy and three drying-kinetics laws.

Sorption: the GAB isotherm (Guggenheim-Anderson-de Boer; van den Berg and Bruin 1981)
``X = Xm C K a / ((1 - K a)(1 - K a + C K a))`` with ``Xm = Xm0 exp(-lam (T - 298.15))``,
``C = C0 exp(E_C (1/T - 1/298.15))``, ``K = K0 exp(E_K (1/T - 1/298.15))`` (the Arrhenius form of
Quirijns et al. 2005 and Timmermann 2003). With ``Xm0 = 0.06, C0 = 8, K0 = 0.8`` it gives
0.057 / 0.112 / 0.204 / 0.29 kg/kg at 30 / 65 / 90 / 100 % relative humidity and 25 °C,
close to the softwood sorption data of the Wood Handbook (FPL-GTR-282, Table 4-2). Its
inverse ``a_w(X, T)`` is the positive root of a quadratic, capped at 1 above the fibre
saturation value ``X(a=1)``.

Differential heat of sorption (excess over the latent heat): ``q(X) = q0 exp(-X / Xq)``, the
exponential form fitted to wood by Stamm (*Wood and Cellulose Science*, 1964, ch. 12) and
Skaar (*Wood-Water Relations*, 1988, ch. 4), ``q0`` about 1.0 to 1.2 MJ/kg, ``Xq`` 0.06 to
0.09 kg/kg.

Fibre enthalpy per kg dry fibre: ``e_f = s_cp h_s(T) + X c_w (T - T0) - q0 Xq exp(-X/Xq)`` with
the dry-wood heat capacity ``c_p0 = 103.1 + 3.867 T`` J/(kg K) (Wood Handbook eq. 4-20), so
that releasing water from the fibre costs ``c_w (T - T0) + q(X)`` per kg on top of its
evaporation. The temperature follows in closed form (a quadratic in ``T``).

Kinetics (``variant`` in the parameter vector), each returning the evaporation flux
``N`` [kg/(m2 s)] for a low-flux gas-side conductance ``g`` [kg/(m2 s)] in the high-flux
(Stefan) form ``N = g ln((1 - w_inf) / (1 - w_s))`` (Bird, Stewart and Lightfoot, *Transport
Phenomena*, 2nd ed., eq. 22.8-22); a negative ``N`` is re-adsorption:

0. **REA**, reaction-engineering approach (Chen and Xie 1997; Chen 2008, *Drying Technology*
   26:627): surface vapour pressure ``p_sat(T_f) exp(-dE_v / (R T_f))`` with
   ``dE_v = dE_b exp(-b (kappa (X - X_b))^c)``, ``dE_b = -R T_g ln RH_g`` and ``X_b`` the
   equilibrium moisture at the gas state. Below ``X_b`` the surface follows the isotherm
   (``dE_v = -R T_g ln a_w(X, T_g)``), which joins continuously at ``X_b``.
1. **Characteristic drying curve** (van Meel 1958; Keey, *Drying of Loose and Particulate
   Materials*, 1992, ch. 4): ``N = f N_wb`` with the saturated-surface rate ``N_wb`` and
   ``f = min(1, (kappa (X - X_e) / (X_cr - X_e))^n)``, ``X_e`` the equilibrium moisture with the
   gas vapour at the fibre's temperature; below ``X_e`` the surface follows the isotherm.
2. **Two resistances in series** (external film, internal transport; e.g. Pakowski and
   Mujumdar, *Handbook of Industrial Drying*, 4th ed., ch. 4): the core holds vapour at
   ``a_w(X, T_f) p_sat(T_f)`` and feeds the surface through ``K_i (w_core - w_s)`` with
   ``K_i = kappa k0 exp(-E_a/R (1/T_f - 1/T_ref)) exp(beta (X - 1))``, which falls (the internal
   resistance grows) as the fibre dries; the surface mass fraction ``w_s`` solves the series
   condition with the Stefan film by a safeguarded Newton iteration.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from softsensor.plant.independent.layout import (
    P_CP_SCALE,
    P_GAB_C,
    P_GAB_EC,
    P_GAB_EK,
    P_GAB_K,
    P_GAB_LAM,
    P_GAB_XM,
    P_KA,
    P_KAPPA,
    P_KB,
    P_KC,
    P_M_DG,
    P_PRESSURE,
    P_Q_SORP,
    P_VARIANT,
    P_X_SORP,
)
from softsensor.plant.independent.properties import (
    C_WATER,
    R_U,
    T0,
    p_sat,
    vapour_mass_fraction,
)

VARIANTS: tuple[str, ...] = ("rea", "cdc", "two_resistance")
T_REF_SORPTION = 298.15  # K
T_REF_KINETICS = 350.0   # K, where the two-resistance k0 is given
W_SURFACE_MAX = 0.99     # cap of the surface vapour mass fraction (boiling fibre)
_CP_A, _CP_B = 103.1, 3.867  # dry wood c_p0 = a + b T [J/(kg K)], Wood Handbook eq. 4-20


@njit(cache=True)
def _gab_constants(T: float, p: np.ndarray) -> tuple[float, float, float]:
    d = 1.0 / T - 1.0 / T_REF_SORPTION
    xm = p[P_GAB_XM] * math.exp(-p[P_GAB_LAM] * (T - T_REF_SORPTION))
    c = max(p[P_GAB_C] * math.exp(p[P_GAB_EC] * d), 1.01)
    k = p[P_GAB_K] * math.exp(p[P_GAB_EK] * d)
    return xm, c, k


@njit(cache=True)
def x_equilibrium(a: float, T: float, p: np.ndarray) -> float:
    """Equilibrium moisture [kg/kg dry] at water activity ``a`` [-] and ``T`` [K] (GAB)."""
    xm, c, k = _gab_constants(T, p)
    a = min(max(a, 0.0), 1.0)
    u = k * a
    return xm * c * u / ((1.0 - u) * (1.0 - u + c * u))


@njit(cache=True)
def water_activity(X: float, T: float, p: np.ndarray) -> float:
    """Water activity [-] of fibre at moisture ``X`` [kg/kg] and ``T`` [K]; 1 above the
    saturation value of the isotherm (inverse of :func:`x_equilibrium`)."""
    if X <= 0.0:
        return 0.0
    xm, c, k = _gab_constants(T, p)
    b = xm * c - X * (c - 2.0)
    u = 2.0 * X / (b + math.sqrt(b * b + 4.0 * X * X * (c - 1.0)))
    return min(u / k, 1.0)


@njit(cache=True)
def sorption_heat(X: float, p: np.ndarray) -> float:
    """Differential heat of sorption in excess of the latent heat [J/kg water]."""
    return p[P_Q_SORP] * math.exp(-max(X, 0.0) / p[P_X_SORP])


@njit(cache=True)
def _h_dry(T: float) -> float:
    return _CP_A * (T - T0) + 0.5 * _CP_B * (T * T - T0 * T0)


@njit(cache=True)
def fibre_enthalpy(T: float, X: float, p: np.ndarray) -> float:
    """Enthalpy of moist fibre [J/kg dry fibre] at ``T`` [K] and moisture ``X`` [kg/kg]."""
    bound = p[P_Q_SORP] * p[P_X_SORP] * math.exp(-max(X, 0.0) / p[P_X_SORP])
    return p[P_CP_SCALE] * _h_dry(T) + X * C_WATER * (T - T0) - bound


@njit(cache=True)
def fibre_temperature(e: float, X: float, p: np.ndarray) -> float:
    """Temperature [K] of fibre with enthalpy ``e`` [J/kg dry] and moisture ``X`` (closed form)."""
    s = p[P_CP_SCALE]
    bound = p[P_Q_SORP] * p[P_X_SORP] * math.exp(-max(X, 0.0) / p[P_X_SORP])
    qa = 0.5 * s * _CP_B
    qb = s * _CP_A + X * C_WATER
    qc = -(s * _CP_A * T0 + 0.5 * s * _CP_B * T0 * T0 + X * C_WATER * T0) - (e + bound)
    return 2.0 * (-qc) / (qb + math.sqrt(qb * qb - 4.0 * qa * qc))


@njit(cache=True)
def fibre_cp(T: float, X: float, p: np.ndarray) -> float:
    """Heat capacity of moist fibre at constant moisture [J/(K kg dry fibre)]."""
    return p[P_CP_SCALE] * (_CP_A + _CP_B * T) + X * C_WATER


@njit(cache=True)
def _stefan(g: float, w_inf: float, w_s: float) -> float:
    w_s = min(w_s, W_SURFACE_MAX)
    return g * math.log((1.0 - w_inf) / (1.0 - w_s))


@njit(cache=True)
def evaporation_flux(X: float, T_f: float, T_g: float, pv: float, w_inf: float, g: float,
                     p: np.ndarray) -> float:
    """Evaporation flux [kg/(m2 s)] of the drawn kinetics law (module docstring).

    ``X`` fibre moisture [kg/kg], ``T_f``/``T_g`` fibre and gas temperature [K], ``pv`` gas
    vapour pressure [Pa], ``w_inf`` gas vapour mass fraction [-], ``g`` low-flux gas-side
    mass-transfer conductance [kg/(m2 s)].
    """
    variant = int(p[P_VARIANT])
    kappa = p[P_KAPPA]
    pres = p[P_PRESSURE]
    m_dg = p[P_M_DG]
    ps_f = p_sat(T_f)
    if variant == 0:
        rh_b = min(max(pv / p_sat(T_g), 1e-9), 1.0)
        de_b = -R_U * T_g * math.log(rh_b)
        x_b = x_equilibrium(rh_b, T_g, p)
        if X >= x_b:
            de = de_b * math.exp(-p[P_KA] * (kappa * (X - x_b)) ** p[P_KB])
        else:
            de = -R_U * T_g * math.log(max(water_activity(X, T_g, p), 1e-9))
        pvs = ps_f * math.exp(-de / (R_U * T_f))
        return _stefan(g, w_inf, vapour_mass_fraction(min(pvs, pres), m_dg, pres))
    if variant == 1:
        rh_f = min(pv / ps_f, 1.0)
        x_e = x_equilibrium(rh_f, T_f, p)
        if X >= x_e:
            phi = kappa * (X - x_e) / (p[P_KA] - x_e)
            f = min(1.0, phi ** p[P_KB])
            n_wb = _stefan(g, w_inf, vapour_mass_fraction(min(ps_f, pres), m_dg, pres))
            return f * n_wb
        pvs = water_activity(X, T_f, p) * ps_f
        return _stefan(g, w_inf, vapour_mass_fraction(min(pvs, pres), m_dg, pres))
    # two resistances in series
    p_core = min(water_activity(X, T_f, p) * ps_f, pres)
    w_c = min(vapour_mass_fraction(p_core, m_dg, pres), W_SURFACE_MAX)
    k_i = kappa * p[P_KA] * math.exp(-p[P_KB] / R_U * (1.0 / T_f - 1.0 / T_REF_KINETICS)) \
        * math.exp(p[P_KC] * (X - 1.0))
    # K_i (v - v_c) + g ln(v / v_inf) = 0 for v = 1 - w_s, bracketed between v_c and v_inf
    v_c = 1.0 - w_c
    v_inf = 1.0 - w_inf
    lo = min(v_c, v_inf)
    hi = max(v_c, v_inf)
    if hi - lo < 1e-15:
        return 0.0
    v = (k_i * v_c + g * v_inf / v_inf) / (k_i + g / v_inf)  # low-flux series estimate
    v = min(max(v, lo), hi)
    for _ in range(60):
        f = k_i * (v - v_c) + g * math.log(v / v_inf)
        step = f / (k_i + g / v)
        if abs(step) < 1e-15:
            break
        if f > 0.0:
            hi = v
        else:
            lo = v
        v_new = v - step
        # Newton stays inside the bracket; if it would leave it, bisect instead
        v = v_new if lo < v_new < hi else 0.5 * (lo + hi)
    return g * math.log(v_inf / v)


def gab_reference_values(p: np.ndarray) -> dict[str, float]:
    """Equilibrium moistures [kg/kg] at a few states, for the structure printout."""
    return {f"X_eq({int(rh * 100)}%,{int(T)}K)": float(x_equilibrium(rh, T, p))
            for T, rh in ((298.15, 0.65), (348.0, 0.4), (373.15, 0.1))}
