"""Humid combustion gas and water: thermodynamic and transport properties (compiled).

The drying gas is a *dry gas* (air with some combustion CO2, CO2 mass fraction ``w``) carrying
water vapour (humidity ratio ``Y`` [kg water / kg dry gas]). Every enthalpy is referred to
``T0 = 273.15 K`` with the dry-gas species and *liquid* water at zero there, so vapour carries
its latent heat. Sources:

* ideal-gas heat capacities and enthalpies: NASA 7-coefficient polynomials, low-temperature
  range (200/300 to 1000 K), as tabulated in GRI-Mech 3.0 ``thermo30.dat`` (Smith et al.
  1999; McBride, Gordon and Reno, NASA TM-4513, 1993); air as 75.53 % N2, 23.14 % O2,
  1.33 % Ar by mass;
* latent heat at 0 °C, 2.5008 MJ/kg, and liquid water at a constant 4186 J/(kg K)
  (IAPWS-95 values at 0 °C and the 0 to 100 °C mean);
* saturation pressure: Wagner and Pruss (1993), the IAPWS 1992 six-term equation, used below
  0 °C over supercooled water as meteorology defines relative humidity;
* viscosities and conductivities: Sutherland's law for air (White, *Viscous Fluid Flow*,
  3rd ed., Table 1-2 and 1-3), linear fits of steam at low pressure (VDI Heat Atlas D2.1,
  373 to 473 K), mixed by Wilke's rule and the Wassiljewa/Mason-Saxena equation (Poling,
  Prausnitz, O'Connell, *The Properties of Gases and Liquids*, 5th ed., eqs. 9-5.13 and
  10-6.1); the small CO2 share is treated as air in the transport properties;
* binary diffusivity of water vapour in air: Marrero and Mason (1972) power laws.

All functions take SI units and are compiled with numba; the dry-gas composition enters as a
5-coefficient mass-based ``cp`` polynomial (:func:`dry_gas_coefficients`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

T0 = 273.15                 # K, enthalpy reference
R_U = 8.314462618           # J/(mol K)
M_W = 0.01801528            # kg/mol, water
M_AIR = 0.0289647           # kg/mol, dry air
M_CO2 = 0.0440095           # kg/mol
R_V = R_U / M_W             # J/(kg K), water vapour
DH_VAP0 = 2.5008e6          # J/kg, latent heat at T0
C_WATER = 4186.0            # J/(kg K), liquid water
SIGMA = 5.670374419e-8      # W/(m2 K4), Stefan-Boltzmann
G_ACC = 9.80665             # m/s2

# NASA 7-coefficient low-range polynomials cp/R = a1 + a2 T + a3 T^2 + a4 T^3 + a5 T^4
_NASA = {
    "N2": (3.298677, 1.4082404e-3, -3.963222e-6, 5.641515e-9, -2.444854e-12),
    "O2": (3.78245636, -2.99673416e-3, 9.84730201e-6, -9.68129509e-9, 3.24372837e-12),
    "AR": (2.5, 0.0, 0.0, 0.0, 0.0),
    "CO2": (2.35677352, 8.98459677e-3, -7.12356269e-6, 2.45919022e-9, -1.43699548e-13),
    "H2O": (4.19864056, -2.03643410e-3, 6.52040211e-6, -5.48797062e-9, 1.77197817e-12),
}
_MOLAR = {"N2": 0.0280134, "O2": 0.0319988, "AR": 0.039948, "CO2": M_CO2, "H2O": M_W}
_AIR_MASS = {"N2": 0.7553, "O2": 0.2314, "AR": 0.0133}


def _mass_poly(species: str) -> np.ndarray:
    return np.array(_NASA[species]) * R_U / _MOLAR[species]


CP_AIR = sum(w * _mass_poly(s) for s, w in _AIR_MASS.items()) / sum(_AIR_MASS.values())
CP_CO2 = _mass_poly("CO2")
CP_VAP = _mass_poly("H2O")


@njit(cache=True)
def dry_gas_coefficients(w_co2: float) -> np.ndarray:
    """Mass-based ``cp`` polynomial [J/(kg K) per T^k] of air with CO2 mass fraction ``w_co2``."""
    return (1.0 - w_co2) * CP_AIR + w_co2 * CP_CO2


@njit(cache=True)
def dry_gas_molar_mass(w_co2: float) -> float:
    """Molar mass of the dry gas [kg/mol] for a CO2 mass fraction ``w_co2`` [-]."""
    return 1.0 / ((1.0 - w_co2) / M_AIR + w_co2 / M_CO2)


@njit(cache=True)
def poly_cp(c: np.ndarray, T: float) -> float:
    """Heat capacity [J/(kg K)] from a mass-based 5-coefficient polynomial at ``T`` [K]."""
    return c[0] + T * (c[1] + T * (c[2] + T * (c[3] + T * c[4])))


@njit(cache=True)
def _poly_h(c: np.ndarray, T: float) -> float:
    return T * (c[0] + T * (c[1] / 2.0 + T * (c[2] / 3.0 + T * (c[3] / 4.0 + T * c[4] / 5.0))))


@njit(cache=True)
def poly_h(c: np.ndarray, T: float) -> float:
    """Sensible enthalpy ``int_T0^T cp dT`` [J/kg] of a polynomial ``cp``."""
    return _poly_h(c, T) - _poly_h(c, T0)


@njit(cache=True)
def h_vapour(T: float) -> float:
    """Enthalpy of water vapour [J/kg] at ``T`` [K] (liquid water at T0 is zero)."""
    return DH_VAP0 + poly_h(CP_VAP, T)


@njit(cache=True)
def h_liquid(T: float) -> float:
    """Enthalpy of liquid water [J/kg] at ``T`` [K]."""
    return C_WATER * (T - T0)


@njit(cache=True)
def gas_enthalpy(cdg: np.ndarray, T: float, Y: float) -> float:
    """Enthalpy of humid gas [J/kg dry gas] at ``T`` [K] and humidity ratio ``Y`` [kg/kg]."""
    return poly_h(cdg, T) + Y * h_vapour(T)


@njit(cache=True)
def gas_cp(cdg: np.ndarray, T: float, Y: float) -> float:
    """Heat capacity of humid gas [J/(K kg dry gas)]."""
    return poly_cp(cdg, T) + Y * poly_cp(CP_VAP, T)


@njit(cache=True)
def gas_temperature(cdg: np.ndarray, e: float, Y: float) -> float:
    """Temperature [K] of humid gas with enthalpy ``e`` [J/kg dry gas] (Newton on h(T))."""
    ev = e - Y * DH_VAP0
    T = T0 + ev / (1010.0 + 1870.0 * Y)
    # Newton to machine precision: the march differentiates the right-hand side numerically,
    # so the temperature must not carry iteration noise
    for _ in range(30):
        f = poly_h(cdg, T) + Y * poly_h(CP_VAP, T) - ev
        dT = f / (poly_cp(cdg, T) + Y * poly_cp(CP_VAP, T))
        T -= dT
        if abs(dT) < 1e-7:
            f = poly_h(cdg, T) + Y * poly_h(CP_VAP, T) - ev
            return T - f / (poly_cp(cdg, T) + Y * poly_cp(CP_VAP, T))
    return T


@njit(cache=True)
def p_sat(T: float) -> float:
    """Saturation pressure of water [Pa] at ``T`` [K] (Wagner and Pruss 1993)."""
    tc = 647.096
    tau = 1.0 - T / tc
    st = math.sqrt(tau)
    t3 = tau * tau * tau
    ln = (tc / T) * (-7.85951783 * tau + 1.84408259 * tau * st - 11.7866497 * t3
                     + 22.6807411 * t3 * st - 15.9618719 * t3 * tau
                     + 1.80122502 * t3 * t3 * tau * st)
    return 22.064e6 * math.exp(ln)


@njit(cache=True)
def vapour_pressure(Y: float, m_dg: float, p: float) -> float:
    """Partial pressure of water vapour [Pa] in gas of humidity ``Y`` [kg/kg], dry molar mass
    ``m_dg`` [kg/mol] at total pressure ``p`` [Pa]."""
    n = Y / M_W
    return p * n / (n + 1.0 / m_dg)


@njit(cache=True)
def humidity_from_vapour_pressure(pv: float, m_dg: float, p: float) -> float:
    """Humidity ratio [kg/kg dry gas] of gas with vapour pressure ``pv`` [Pa]."""
    return (M_W / m_dg) * pv / (p - pv)


@njit(cache=True)
def vapour_mass_fraction(pv: float, m_dg: float, p: float) -> float:
    """Mass fraction of vapour [-] in humid gas with vapour pressure ``pv`` [Pa]."""
    a = pv * M_W
    return a / (a + (p - pv) * m_dg)


@njit(cache=True)
def density(T: float, Y: float, m_dg: float, p: float) -> float:
    """Density of humid gas [kg/m3]: ideal gas, dry gas plus vapour."""
    n_per_kg_dry = 1.0 / m_dg + Y / M_W  # mol per kg dry gas
    return p * (1.0 + Y) / (n_per_kg_dry * R_U * T)


@njit(cache=True)
def diffusivity(T: float, p: float) -> float:
    """Binary diffusivity of water vapour in air [m2/s] (Marrero and Mason 1972)."""
    if T < 450.0:
        return 1.87e-10 * T ** 2.072 * 101325.0 / p
    return 2.75e-9 * T ** 1.632 * 101325.0 / p


@njit(cache=True)
def transport(T: float, Y: float) -> tuple[float, float]:
    """Dynamic viscosity [Pa s] and thermal conductivity [W/(m K)] of humid gas."""
    mu_a = 1.716e-5 * (T / 273.15) ** 1.5 * (273.15 + 110.4) / (T + 110.4)
    k_a = 0.0241 * (T / 273.15) ** 1.5 * (273.15 + 194.0) / (T + 194.0)
    mu_v = 1.23e-5 + 3.9e-8 * (T - 373.15)
    k_v = 0.0248 + 8.3e-5 * (T - 373.15)
    x_v = (Y / M_W) / (Y / M_W + 1.0 / M_AIR)
    x_a = 1.0 - x_v
    r = math.sqrt(mu_a / mu_v)
    phi_av = (1.0 + r * (M_W / M_AIR) ** 0.25) ** 2 / math.sqrt(8.0 * (1.0 + M_AIR / M_W))
    phi_va = phi_av * (mu_v / mu_a) * (M_AIR / M_W)
    da = x_a + x_v * phi_av
    dv = x_v + x_a * phi_va
    return x_a * mu_a / da + x_v * mu_v / dv, x_a * k_a / da + x_v * k_v / dv


@njit(cache=True)
def temperature_of(e: float, Y: float, w_co2: float) -> float:
    """Temperature [K] of humid gas with enthalpy ``e`` [J/kg dry], humidity ``Y`` [kg/kg]
    and CO2 mass fraction ``w_co2`` [-] of its dry gas."""
    return gas_temperature(dry_gas_coefficients(w_co2), e, Y)


@njit(cache=True)
def burner_mix(frac: float, T_hot: float, Y_hot: float, w_hot: float, T_amb: float,
               H_amb: float) -> tuple[float, float, float]:
    """Burner gas (CO2 share ``w_hot`` of its dry gas) mixed adiabatically with ambient air at
    hot dry-gas share ``frac``: enthalpy [J/kg dry], humidity [kg/kg], CO2 share [-]."""
    e = frac * gas_enthalpy(dry_gas_coefficients(w_hot), T_hot, Y_hot) \
        + (1.0 - frac) * gas_enthalpy(CP_AIR, T_amb, H_amb)
    return e, frac * Y_hot + (1.0 - frac) * H_amb, frac * w_hot
