"""Humid-air properties, SI units, vectorised.

The humidity variable is the humidity ratio ``Y`` [kg water / kg dry air] throughout (the
paper's "specific humidity" ``H_a`` and the contract's ``H_amb`` are humidity ratios too).
Enthalpies are per kg of dry air and referenced to liquid water and dry air at 0 °C
(ASHRAE 2017 Fundamentals ch. 1), so that the tube's energy balance closes exactly with the
fibre enthalpy of :mod:`softsensor.model.wood`. ASHRAE's eq. 32 takes constant heat
capacities (1006 and 1860 J/(kg K)); over a dryer's 350 to 500 K they are 1 and 4 % low, which
biases the air-side duty by 1 to 2 % depending on ``T_air_in``. Here the dry-air and vapour
ideal-gas heat capacities are quadratics in ``T`` fitted to CoolProp (Lemmon air, IAPWS-95)
over 250 to 600 K (within 0.06 % and 0.16 %), and the enthalpies are their exact integrals,
so ``dh/dT`` is exactly the heat capacity and the balances still close to round-off.

Every function here is plain numpy arithmetic so that the same source serves array callers and
the numba kernels: ``numba.extending.register_jitable`` leaves them ordinary Python functions
and compiles them inline where :mod:`softsensor.model.kernels` calls them; hence ``np.minimum``
and ``np.maximum`` instead of ``if``.

References
----------
[1] ASHRAE Handbook Fundamentals 2017, ch. 1 (Psychrometrics): eqs. 5-6 (saturation pressure,
    Hyland-Wexler), 20 (humidity ratio), 28 (moist-air volume), 32 (enthalpy).
[2] Tsilingiris, P.T. (2008), Energy Convers. Manage. 49, 1098-1110: viscosity and thermal
    conductivity of moist air (Wilke / Mason-Saxena mixing).
[3] Marrero, T.R., Mason, E.A. (1972), J. Phys. Chem. Ref. Data 1, 3: D_va = 1.87e-10
    T^2.072 / P [atm] (280-450 K), used for the vapour diffusivity.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

T0 = 273.15  # K, reference temperature of all enthalpies
R_DA = 287.042  # J/(kg K), dry air gas constant, ASHRAE 2017 ch. 1
EPS = 0.621945  # M_w / M_da, ASHRAE 2017 ch. 1 eq. 20
#: Ideal-gas heat capacity of dry air ``c_pa = a0 + a1 T + a2 T^2`` [J/(kg K)], least-squares
#: fit to CoolProp's Lemmon et al. (2000) air over 250-600 K (max. deviation 0.06 %).
CPA_COEF = (1019.0975, -0.14970312, 3.3945888e-4)
#: Ideal-gas heat capacity of water vapour [J/(kg K)], fit to CoolProp's IAPWS-95 at low
#: density over 250-600 K (max. deviation 0.16 %).
CPV_COEF = (1839.8493, -0.12736632, 7.1029276e-4)
C_W = 4186.0  # J/(kg K), liquid water
H_FG0 = 2.501e6  # J/kg, latent heat at 0 °C, ASHRAE 2017 ch. 1 eq. 32
#: Cap on the saturation pressure relative to total pressure, so that ``Y_s`` stays finite
#: when wet fibre enters near or above 100 °C (the steam flash at the injection point).
P_SAT_CAP = 0.999


@register_jitable
def p_sat(T):
    """Saturation pressure of water vapour over liquid water ``p_ws`` [Pa].

    Hyland-Wexler, ASHRAE 2017 ch. 1 eq. 6 (valid 0 to 200 °C; used to 480 K).

    Parameters
    ----------
    T : array_like
        Temperature [K].
    """
    C8, C9, C10 = -5.8002206e3, 1.3914993, -4.8640239e-2
    C11, C12, C13 = 4.1764768e-5, -1.4452093e-8, 6.5459673
    return np.exp(C8 / T + C9 + C10 * T + C11 * T * T + C12 * T * T * T + C13 * np.log(T))


@register_jitable
def humidity_ratio(p_w, P):
    """Humidity ratio ``Y`` [kg/kg] from vapour partial pressure ``p_w`` [Pa], ASHRAE eq. 20."""
    return EPS * p_w / (P - p_w)


@register_jitable
def vapour_pressure(Y, P):
    """Vapour partial pressure ``p_w`` [Pa] of air with humidity ratio ``Y`` [kg/kg]."""
    return P * Y / (EPS + Y)


@register_jitable
def y_sat(T, P):
    """Humidity ratio of saturated air ``Y_s`` [kg/kg] at ``T`` [K], ``P`` [Pa].

    ASHRAE eq. 20 with ``p_ws`` capped at ``P_SAT_CAP * P`` (see module notes).
    """
    pw = np.minimum(p_sat(T), P_SAT_CAP * P)
    return EPS * pw / (P - pw)


@register_jitable
def relative_humidity(T, Y, P):
    """Relative humidity ``phi`` [-] of air at ``T`` [K], ``Y`` [kg/kg], ``P`` [Pa].

    Above 100 °C the saturation pressure exceeds ``P``; ``phi`` is then the ratio to the
    (uncapped) saturation pressure, as the sorption isotherm needs.
    """
    return vapour_pressure(Y, P) / p_sat(T)


@register_jitable
def dry_air_density(T, Y, P):
    """Dry air per volume of moist air ``rho_da`` [kg dry air / m3], ASHRAE eq. 28."""
    return P / (R_DA * T * (1.0 + 1.607858 * Y))


@register_jitable
def density(T, Y, P):
    """Moist-air density ``rho`` [kg/m3] (dry air plus vapour), ASHRAE eq. 28.

    Humid air is lighter than dry air at the same ``T`` and ``P``.
    """
    return (1.0 + Y) * dry_air_density(T, Y, P)


@register_jitable
def _poly_cp(c, T):
    return c[0] + c[1] * T + c[2] * T * T


@register_jitable
def _poly_h(c, T):
    """``int_T0^T (c0 + c1 T + c2 T^2) dT``."""
    return (c[0] * (T - T0) + 0.5 * c[1] * (T * T - T0 * T0)
            + c[2] / 3.0 * (T * T * T - T0 * T0 * T0))


@register_jitable
def dry_air_heat_capacity(T):
    """Ideal-gas heat capacity of dry air ``c_pa`` [J/(kg K)] at ``T`` [K] (:data:`CPA_COEF`)."""
    return _poly_cp(CPA_COEF, T)


@register_jitable
def vapour_heat_capacity(T):
    """Ideal-gas heat capacity of water vapour ``c_pv`` [J/(kg K)] at ``T`` [K]
    (:data:`CPV_COEF`)."""
    return _poly_cp(CPV_COEF, T)


@register_jitable
def dry_air_enthalpy(T):
    """Dry-air enthalpy ``h_da`` [J/kg] above 0 °C: the integral of
    :func:`dry_air_heat_capacity`."""
    return _poly_h(CPA_COEF, T)


@register_jitable
def vapour_enthalpy(T):
    """Enthalpy of water vapour ``h_v`` [J/kg] at ``T`` [K], reference liquid water at 0 °C:
    ``H_FG0`` plus the integral of :func:`vapour_heat_capacity`."""
    return H_FG0 + _poly_h(CPV_COEF, T)


@register_jitable
def enthalpy(T, Y):
    """Moist-air enthalpy ``h = h_da(T) + Y h_v(T)`` [J / kg dry air] (ASHRAE 2017 ch. 1 eq.
    30 with temperature-dependent heat capacities, see module notes)."""
    return dry_air_enthalpy(T) + Y * vapour_enthalpy(T)


@register_jitable
def heat_capacity(T, Y):
    """Humid heat ``c_a = dh/dT`` at constant ``Y`` [J / (kg dry air K)]."""
    return dry_air_heat_capacity(T) + Y * vapour_heat_capacity(T)


@register_jitable
def temperature(h, Y):
    """Temperature [K] of moist air with enthalpy ``h`` [J / kg dry air] and humidity ratio
    ``Y`` [kg/kg]: the inverse of :func:`enthalpy` (Newton from the constant-``c_p`` guess;
    ``h`` is strictly increasing in ``T``, four steps reach round-off)."""
    T = T0 + (h - Y * H_FG0) / (1006.0 + 1860.0 * Y)
    for _ in range(4):
        T = T - (enthalpy(T, Y) - h) / heat_capacity(T, Y)
    return T


@register_jitable
def latent_heat(T):
    """Latent heat of vaporisation ``h_fg`` [J/kg] = vapour minus liquid enthalpy at ``T``.

    Ideal-gas vapour (:func:`vapour_enthalpy`) against liquid of constant ``C_W``, consistent
    with the enthalpies the balances use; within 1 % of IAPWS-95 over 0 to 120 °C, where
    liquid water exists in the dryer.
    """
    return vapour_enthalpy(T) - C_W * (T - T0)


@register_jitable
def _mole_fraction_vapour(Y):
    return Y / (EPS + Y)


@register_jitable
def _component_viscosities(T):
    """Dry air (Sutherland) and water vapour (linear fit) viscosities [Pa s]."""
    mu_a = 1.716e-5 * (T / 273.15) ** 1.5 * (273.15 + 110.4) / (T + 110.4)
    mu_v = 8.02e-6 + 4.0e-8 * (T - 273.15)
    return mu_a, mu_v


@register_jitable
def _wilke_weights(Y, mu_a, mu_v):
    """Mole fractions and Wilke's interaction weights [2] ``(x_a, x_v, phi_av, phi_va)`` from
    the component viscosities ``mu_a``, ``mu_v``."""
    xv = _mole_fraction_vapour(Y)
    xa = 1.0 - xv
    ma, mv = 28.9645, 18.01528
    phi_av = (1.0 + (mu_a / mu_v) ** 0.5 * (mv / ma) ** 0.25) ** 2 / (8.0 * (1.0 + ma / mv)) ** 0.5
    phi_va = (1.0 + (mu_v / mu_a) ** 0.5 * (ma / mv) ** 0.25) ** 2 / (8.0 * (1.0 + mv / ma)) ** 0.5
    return xa, xv, phi_av, phi_va


@register_jitable
def _mix(weights, prop_a, prop_v):
    """Wilke's mixing rule [2] of a dry-air and a vapour property with
    :func:`_wilke_weights`."""
    xa, xv, phi_av, phi_va = weights
    return xa * prop_a / (xa + xv * phi_av) + xv * prop_v / (xv + xa * phi_va)


@register_jitable
def _wilke_mix(Y, mu_a, mu_v, prop_a, prop_v):
    """Wilke's mixing rule [2] of a dry-air and a vapour property, weights from the component
    viscosities ``mu_a``, ``mu_v``."""
    return _mix(_wilke_weights(Y, mu_a, mu_v), prop_a, prop_v)


@register_jitable
def _component_conductivities(T):
    """Dry air (Sutherland-type) and water vapour (quadratic fit) conductivities [W/(m K)]."""
    k_a = 0.02414 * (T / 273.15) ** 1.5 * (273.15 + 194.4) / (T + 194.4)
    k_v = 0.0176 + 5.87e-5 * (T - 273.15) + 1.04e-7 * (T - 273.15) ** 2
    return k_a, k_v


@register_jitable
def viscosity(T, Y):
    """Dynamic viscosity of moist air ``mu`` [Pa s].

    Dry air by Sutherland's law, vapour by a linear fit, mixed by Wilke's rule [2].
    """
    mu_a, mu_v = _component_viscosities(T)
    return _wilke_mix(Y, mu_a, mu_v, mu_a, mu_v)


@register_jitable
def conductivity(T, Y):
    """Thermal conductivity of moist air ``k`` [W/(m K)].

    Dry air by a Sutherland-type law, vapour by a quadratic fit, mixed with Wilke's weights [2].
    """
    k_a, k_v = _component_conductivities(T)
    mu_a, mu_v = _component_viscosities(T)
    return _wilke_mix(Y, mu_a, mu_v, k_a, k_v)


@register_jitable
def viscosity_conductivity(T, Y):
    """``(viscosity(T, Y), conductivity(T, Y))``, the same numbers, for callers that need both
    at one state (the model's kernels, once per cell balance): the component viscosities and
    Wilke's weights, the costly part, are computed once."""
    mu_a, mu_v = _component_viscosities(T)
    weights = _wilke_weights(Y, mu_a, mu_v)
    k_a, k_v = _component_conductivities(T)
    return _mix(weights, mu_a, mu_v), _mix(weights, k_a, k_v)


@register_jitable
def vapour_diffusivity(T, P):
    """Binary diffusion coefficient of water vapour in air ``D_va`` [m2/s] [3]."""
    return 1.87e-10 * T**2.072 * (101325.0 / P)


@register_jitable
def heat_capacity_mass(T, Y):
    """Heat capacity per kg of moist air ``c_p`` [J/(kg K)], for Pr and Chilton-Colburn."""
    return heat_capacity(T, Y) / (1.0 + Y)


@register_jitable
def prandtl_number(cp, mu, k):
    """Prandtl number ``Pr = c_p mu / k`` [-] from heat capacity [J/(kg K)], viscosity [Pa s]
    and conductivity [W/(m K)] (the kernels pass the properties they already hold)."""
    return cp * mu / k


@register_jitable
def schmidt_number(mu, rho, D_va):
    """Schmidt number ``Sc = mu / (rho D_va)`` [-], the paper's eq. 1."""
    return mu / (rho * D_va)


@register_jitable
def prandtl(T, Y):
    """Prandtl number of moist air [-]."""
    return prandtl_number(heat_capacity_mass(T, Y), viscosity(T, Y), conductivity(T, Y))


@register_jitable
def schmidt(T, Y, P):
    """Schmidt number of water vapour in moist air [-], the paper's eq. 1."""
    return schmidt_number(viscosity(T, Y), density(T, Y, P), vapour_diffusivity(T, P))
