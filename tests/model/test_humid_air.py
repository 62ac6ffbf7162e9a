"""Humid-air properties (softsensor.model.humid_air) against outside references.

References: psychrolib 2.5 (ASHRAE 2017 Fundamentals ch. 1, ideal-gas psychrometrics; refuses
saturation pressures above 200 °C) and CoolProp (IAPWS-95 water, Lemmon air, and the
real-gas humid air of ASHRAE RP-1485 behind ``HAPropsSI``). Range of the dryer: 280 to 480 K,
humidity ratio 0 to 0.3 kg/kg, 1 atm.
"""

from __future__ import annotations

import numpy as np
import psychrolib
import pytest
from CoolProp.CoolProp import HAPropsSI, PropsSI

from softsensor.model import humid_air as ha

psychrolib.SetUnitSystem(psychrolib.SI)

P = 101325.0
T_GRID = np.linspace(280.0, 480.0, 21)
Y_GRID = np.linspace(0.0, 0.3, 13)
T_PSYCHRO_MAX = 473.15  # psychrolib's saturation pressure refuses anything hotter
M_W, M_A = 18.015268, 28.966  # g/mol, as CoolProp's humid air
#: Where the model and psychrolib evaluate the same ASHRAE equation (Hyland-Wexler eq. 6, the
#: humidity ratio eq. 20, the ideal-gas eq. 28) they differ only by round-off in the order of
#: evaluation: measured at most 3.6e-15 (p_ws; its exponent, about 10, carries a few ulp into
#: the exponential) and 9.3e-15 (Y_s, whose P / (P - p_ws) amplifies that near boiling). This
#: bound leaves ten times that; a coefficient off in its last printed digit (1e-7) fails it.
SAME_EQUATION_RTOL = 1e-13


def _realisable(T: float, Y: float) -> bool:
    """Below saturation: the vapour's partial pressure does not exceed p_ws(T)."""
    return ha.vapour_pressure(Y, P) <= PropsSI("P", "T", min(T, 640.0), "Q", 0, "Water")


# ------------------------------------------------------------------ saturation pressure
def test_saturation_pressure_matches_psychrolib_to_200_C():
    for T in T_GRID[T_GRID <= T_PSYCHRO_MAX]:
        ref = psychrolib.GetSatVapPres(T - 273.15)
        # the same Hyland-Wexler equation: round-off apart (SAME_EQUATION_RTOL)
        assert ha.p_sat(T) == pytest.approx(ref, rel=SAME_EQUATION_RTOL), T


def test_saturation_pressure_matches_iapws_over_the_whole_range():
    # IAPWS-95 (CoolProp) is the primary standard; Hyland-Wexler is fitted to 200 °C and
    # used here to 480 K, so this also checks the extrapolation.
    for T in T_GRID:
        ref = PropsSI("P", "T", T, "Q", 0, "Water")
        # Hyland-Wexler's deviation from IAPWS-95 (a fit to older steam tables), measured
        # at most 2.2e-4 over 280 to 480 K
        assert ha.p_sat(T) == pytest.approx(ref, rel=5e-4), T


def test_saturation_humidity_ratio_matches_psychrolib():
    for T in T_GRID[T_GRID < 370.0]:  # below the boiling point at 1 atm
        ref = psychrolib.GetSatHumRatio(T - 273.15, P)
        assert ha.y_sat(T, P) == pytest.approx(ref, rel=SAME_EQUATION_RTOL), T


def test_saturation_humidity_ratio_is_capped_near_and_above_boiling():
    # the cap keeps Y_s finite when wet fibre reaches 100 °C (module notes)
    cap = ha.EPS * ha.P_SAT_CAP / (1.0 - ha.P_SAT_CAP)
    for T in (373.15, 400.0, 480.0):
        assert np.isfinite(ha.y_sat(T, P))
        assert ha.y_sat(T, P) == pytest.approx(cap, rel=1e-12)


# ------------------------------------------------------------------ density and enthalpy
def test_density_and_enthalpy_match_psychrolib():
    for T in T_GRID:
        for Y in Y_GRID:
            t = T - 273.15
            # psychrolib's ideal-gas density and enthalpy accept any temperature. Density:
            # the same ideal-gas law and gas constant, but psychrolib raises a humidity ratio
            # below 1e-7 to 1e-7, which moves dry air by 6e-8; elsewhere round-off apart
            assert ha.density(T, Y, P) == pytest.approx(
                psychrolib.GetMoistAirDensity(t, Y, P),
                rel=1e-7 if Y == 0.0 else SAME_EQUATION_RTOL), (T, Y)
            # enthalpy: ASHRAE's constant heat capacities against the model's T-dependent
            # ones (module notes), a real difference, measured at most 0.6 % on this grid
            assert ha.enthalpy(T, Y) == pytest.approx(
                psychrolib.GetMoistAirEnthalpy(t, Y), rel=1e-2), (T, Y)


def test_density_and_enthalpy_match_coolprop_real_gas():
    # HAPropsSI (real gas, virial mixing) is the independent reference, above 200 °C too
    n = 0
    for T in T_GRID:
        for Y in Y_GRID:
            if not _realisable(T, Y):
                continue
            rho = 1.0 / HAPropsSI("Vha", "T", T, "P", P, "W", Y)
            h = HAPropsSI("Hda", "T", T, "P", P, "W", Y)
            assert ha.density(T, Y, P) == pytest.approx(rho, rel=1e-2), (T, Y)
            assert ha.enthalpy(T, Y) == pytest.approx(h, rel=1e-2), (T, Y)
            n += 1
    assert n > 150  # most of the grid is realisable in a hot dryer


def test_component_heat_capacities_match_coolprop_ideal_gas():
    # the quadratic fits (module notes) against Lemmon's air and IAPWS-95 vapour at low
    # density, over the dryer's range and beyond: within 0.1 % and 0.2 %
    for T in np.linspace(275.0, 600.0, 14):
        cpa = PropsSI("CP0MASS", "T", T, "P", P, "Air")
        cpv = PropsSI("CP0MASS", "T", T, "Dmass", 1e-4, "Water")
        assert ha.dry_air_heat_capacity(T) == pytest.approx(cpa, rel=1e-3), T
        assert ha.vapour_heat_capacity(T) == pytest.approx(cpv, rel=2e-3), T


def test_air_side_duty_matches_coolprop_real_gas_within_half_a_percent():
    # the heat the tube's air gives up between T_air_in and T_dryer_out at constant humidity
    # (what sets the drying): ASHRAE's constant heat capacities bias it by 1 to 2 % depending
    # on T_air_in; with T-dependent ones it is within 0.5 % of CoolProp's real humid air up to
    # the humidity the tube reaches (0.15; the rest is the vapour's non-ideality)
    for T_in in (440.0, 485.0, 560.0):
        for Y in (0.03, 0.1, 0.15):
            ours = ha.enthalpy(T_in, Y) - ha.enthalpy(348.0, Y)
            ref = (HAPropsSI("Hda", "T", T_in, "P", P, "W", Y)
                   - HAPropsSI("Hda", "T", 348.0, "P", P, "W", Y))
            assert ours == pytest.approx(ref, rel=5e-3), (T_in, Y)


def test_temperature_inverts_enthalpy():
    T = np.array([260.0, 300.0, 348.0, 485.0, 600.0])
    for Y in (0.0, 0.05, 0.3):
        np.testing.assert_allclose(ha.temperature(ha.enthalpy(T, Y), Y), T, rtol=0, atol=1e-9)


def test_humid_air_is_lighter_than_dry_air():
    T = np.array([300.0, 350.0, 450.0])
    assert np.all(ha.density(T, 0.1, P) < ha.density(T, 0.0, P))
    # dry-air content: rho_da (1 + Y) == rho
    np.testing.assert_allclose(ha.dry_air_density(T, 0.1, P) * 1.1, ha.density(T, 0.1, P),
                               rtol=1e-14)


def test_heat_capacity_is_the_temperature_derivative_of_enthalpy():
    T, Y, h = 400.0, 0.12, 1e-3
    dh_dT = (ha.enthalpy(T + h, Y) - ha.enthalpy(T - h, Y)) / (2 * h)
    assert ha.heat_capacity(T, Y) == pytest.approx(dh_dT, rel=1e-9)
    # and dh/dY is the vapour enthalpy at the air temperature (ASHRAE eq. 32)
    dh_dY = (ha.enthalpy(T, Y + 1e-6) - ha.enthalpy(T, Y - 1e-6)) / 2e-6
    assert ha.vapour_enthalpy(T) == pytest.approx(dh_dY, rel=1e-9)


def test_vapour_pressure_and_humidity_ratio_are_inverse():
    Y = np.array([0.0, 0.01, 0.1, 0.3])
    np.testing.assert_allclose(ha.humidity_ratio(ha.vapour_pressure(Y, P), P), Y, atol=1e-15)
    # against psychrolib's partial pressure: eq. 20 inverted, as here (round-off apart)
    for y in Y[1:]:
        assert ha.vapour_pressure(y, P) == pytest.approx(
            psychrolib.GetVapPresFromHumRatio(y, P), rel=SAME_EQUATION_RTOL)


def test_relative_humidity_matches_psychrolib():
    for T, Y in [(300.0, 0.01), (330.0, 0.05), (350.0, 0.2), (420.0, 0.1)]:
        ref = psychrolib.GetRelHumFromHumRatio(T - 273.15, Y, P)
        # p_w / p_ws with the same two equations (round-off apart)
        assert ha.relative_humidity(T, Y, P) == pytest.approx(ref, rel=SAME_EQUATION_RTOL), (T, Y)


# ------------------------------------------------------------------ latent heat
def test_latent_heat_matches_iapws_where_fibre_evaporates():
    # Wet fibre stays below ~105 °C at 1 atm. The linear h_fg (constant c_pv and c_w, so
    # that the enthalpies close exactly) is within 1 % of IAPWS-95 up to 120 °C; above, it
    # drifts (5.6 % at 480 K), where no liquid water exists in the dryer.
    for T in np.linspace(273.16, 393.15, 13):
        ref = (PropsSI("H", "T", T, "Q", 1, "Water") - PropsSI("H", "T", T, "Q", 0, "Water"))
        assert ha.latent_heat(T) == pytest.approx(ref, rel=1e-2), T
    assert ha.latent_heat(ha.T0) == ha.H_FG0


# ------------------------------------------------------------------ transport properties
def _tsilingiris_iapws(T: float, Y: float) -> tuple[float, float]:
    """Viscosity and conductivity of humid air: Tsilingiris (2008) / Wilke mixing of CoolProp
    pure-fluid values, with the vapour at the air temperature and its partial pressure."""
    psi = Y / (ha.EPS + Y)
    mu_a = PropsSI("V", "T", T, "P", P, "Air")
    k_a = PropsSI("L", "T", T, "P", P, "Air")
    rho_v = max(psi * P, 1.0) / (8.314462618 / M_W * 1e3 * T)  # ideal-gas vapour density
    mu_w = PropsSI("V", "T", T, "Dmass", rho_v, "Water")
    k_w = PropsSI("L", "T", T, "Dmass", rho_v, "Water")
    phi_av = (1 + np.sqrt(mu_a / mu_w) * (M_W / M_A) ** 0.25) ** 2 / np.sqrt(8 * (1 + M_A / M_W))
    phi_va = (1 + np.sqrt(mu_w / mu_a) * (M_A / M_W) ** 0.25) ** 2 / np.sqrt(8 * (1 + M_W / M_A))

    def mix(a, w):
        return (1 - psi) * a / ((1 - psi) + psi * phi_av) + psi * w / (psi + (1 - psi) * phi_va)

    return mix(mu_a, mu_w), mix(k_a, k_w)


# Tolerance for transport properties: 2 %. Sutherland's law and the linear vapour fits are
# within 1.4 % (viscosity) and 0.8 % (conductivity) of the IAPWS/Lemmon values over 280-480 K;
# these properties enter only through Re, Pr, Sc in heat-transfer correlations whose own
# scatter is 15-20 % (Churchill-Bernstein, Gnielinski), so 2 % is far below what matters.
TRANSPORT_RTOL = 2e-2


def test_transport_properties_match_coolprop_mixing_rule_with_vapour_at_air_temperature():
    n = 0
    for T in T_GRID:
        for Y in Y_GRID:
            if not _realisable(T, Y):
                continue
            mu, k = _tsilingiris_iapws(T, Y)
            assert ha.viscosity(T, Y) == pytest.approx(mu, rel=TRANSPORT_RTOL), (T, Y)
            assert ha.conductivity(T, Y) == pytest.approx(k, rel=TRANSPORT_RTOL), (T, Y)
            n += 1
    assert n > 150


def test_transport_properties_match_hapropssi_where_its_vapour_state_is_exact():
    # HAPropsSI evaluates the vapour's viscosity and conductivity at saturation at the total
    # pressure (CoolProp src/HumidAirProp.cpp, Viscosity/Conductivity), i.e. at 100 °C
    # whatever the air temperature. It is exact for dry air, nearly so for little vapour,
    # and exact at any humidity at 373.15 K: compare there.
    cases = [(T, Y) for T in T_GRID for Y in (0.0, 0.005, 0.01)]
    cases += [(373.15, Y) for Y in Y_GRID]
    for T, Y in cases:
        if not _realisable(T, Y):
            continue
        mu = HAPropsSI("mu", "T", T, "P", P, "W", Y)
        k = HAPropsSI("k", "T", T, "P", P, "W", Y)
        assert ha.viscosity(T, Y) == pytest.approx(mu, rel=TRANSPORT_RTOL), (T, Y)
        assert ha.conductivity(T, Y) == pytest.approx(k, rel=TRANSPORT_RTOL), (T, Y)


def test_vapour_diffusivity_against_marrero_mason_and_literature_value():
    # D_va at 25 °C, 1 atm is 2.5e-5 to 2.6e-5 m2/s (Bird, Stewart & Lightfoot, table 17.1-1:
    # 2.60e-5 at 298.2 K; Marrero & Mason: 2.56e-5)
    assert ha.vapour_diffusivity(298.15, P) == pytest.approx(2.56e-5, rel=3e-2)
    # inversely proportional to pressure
    assert ha.vapour_diffusivity(350.0, P / 2) == pytest.approx(
        2.0 * ha.vapour_diffusivity(350.0, P), rel=1e-12)


def test_prandtl_and_schmidt_numbers_of_air_are_textbook_values():
    # dry air at 300 K: Pr = 0.707 (Incropera table A.4); water vapour in air: Sc ~ 0.6
    assert ha.prandtl(300.0, 0.0) == pytest.approx(0.707, rel=2e-2)
    assert ha.schmidt(300.0, 0.0, P) == pytest.approx(0.60, rel=5e-2)


# ------------------------------------------------------------------ scalar and array calls
@pytest.mark.parametrize("fn, args", [
    (ha.p_sat, ()), (ha.y_sat, (P,)), (ha.enthalpy, (0.05,)), (ha.density, (0.05, P)),
    (ha.viscosity, (0.05,)), (ha.conductivity, (0.05,)), (ha.latent_heat, ()),
    (ha.vapour_enthalpy, ()), (ha.relative_humidity, (0.05, P)), (ha.prandtl, (0.05,)),
    (ha.schmidt, (0.05, P)), (ha.vapour_diffusivity, (P,)),
])
def test_each_function_takes_a_scalar_and_an_array(fn, args, scalar_and_array):
    scalar_and_array(lambda T: fn(T, *args), [290.0, 350.0, 470.0])


@pytest.mark.parametrize("fn", [
    lambda Y: ha.heat_capacity_mass(350.0, Y), lambda Y: ha.heat_capacity(350.0, Y),
    lambda Y: ha.enthalpy(350.0, Y),
    lambda Y: ha.viscosity(350.0, Y), lambda Y: ha.density(350.0, Y, P),
])
def test_functions_of_humidity_take_a_scalar_and_an_array(fn):
    Y = np.array([0.0, 0.05, 0.3])
    arr = fn(Y)
    assert np.shape(arr) == (3,)
    for i, y in enumerate(Y):
        s = fn(float(y))
        assert np.ndim(s) == 0
        assert s == pytest.approx(arr[i], rel=1e-14)
