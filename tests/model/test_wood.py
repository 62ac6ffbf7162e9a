"""Wood-fibre properties (softsensor.model.wood) against the Wood Handbook and invariants.

Reference: Wood Handbook, FPL-GTR-190 (2010), ch. 4: table 4-2 (equilibrium moisture content,
computed by the handbook from its eq. 4-5, printed to 0.1 % moisture), eq. 4-5 in its
imperial form (°F), eqs. 4-18/4-19 (heat capacity, per kg of moist wood).
"""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.model import wood as wd
from softsensor.model.humid_air import C_W, H_FG0, T0

X_FSP = 0.30


def _F_to_K(t_F: float) -> float:
    return (t_F - 32.0) * 5.0 / 9.0 + T0


# Wood Handbook (2010) table 4-2, rows 30 °F and 70 °F, moisture content in percent.
TABLE_4_2 = {
    30.0: {10: 2.6, 30: 6.3, 50: 9.5, 60: 11.3, 65: 12.4, 80: 16.5, 90: 21.0},
    70.0: {10: 2.5, 30: 6.2, 50: 9.2, 60: 11.0, 65: 12.0, 80: 16.0, 90: 20.5},
}


@pytest.mark.parametrize("t_F", sorted(TABLE_4_2))
def test_equilibrium_moisture_reproduces_wood_handbook_table(t_F):
    # tolerance: the table's print rounding (0.05 %) plus the SI coefficients' rounding
    for rh, mc in TABLE_4_2[t_F].items():
        assert 100.0 * wd.equilibrium_moisture(_F_to_K(t_F), rh / 100.0) == pytest.approx(
            mc, abs=0.1), (t_F, rh)


def test_equilibrium_moisture_twelve_percent_at_20_C_65_percent():
    # the classic indoor value
    assert wd.equilibrium_moisture(293.15, 0.65) == pytest.approx(0.12, abs=0.003)


def _hailwood_horrobin_imperial(t_F, h):
    """Wood Handbook eq. 4-5 with its imperial (°F) coefficients, moisture in percent."""
    W = 330.0 + 0.452 * t_F + 0.00415 * t_F**2
    K = 0.791 + 4.63e-4 * t_F - 8.44e-7 * t_F**2
    K1 = 6.34 + 7.75e-4 * t_F - 9.35e-5 * t_F**2
    K2 = 1.09 + 2.84e-2 * t_F - 9.04e-5 * t_F**2
    Kh = K * h
    return 1800.0 / W * (Kh / (1 - Kh) + (K1 * Kh + 2 * K1 * K2 * Kh**2)
                         / (1 + K1 * Kh + K1 * K2 * Kh**2))


def test_si_coefficients_agree_with_the_imperial_form_up_to_the_clamp():
    # below the 110 °C clamp the SI fit and the °F fit are the same curve
    for t_C in np.linspace(0.0, 110.0, 12):
        for h in (0.05, 0.3, 0.6, 0.9):
            ref = _hailwood_horrobin_imperial(t_C * 9 / 5 + 32, h) / 100.0
            assert wd.equilibrium_moisture(t_C + T0, h) == pytest.approx(ref, abs=2e-3)


def test_equilibrium_moisture_is_clamped_above_110_C_and_stays_non_negative():
    # the fit turns negative above ~129 °C (STACK.md): the model clamps T at 110 °C
    hot = wd.equilibrium_moisture(np.array([383.15, 420.0, 480.0]), 0.05)
    np.testing.assert_allclose(hot, hot[0], rtol=1e-14)
    assert hot[0] > 0.0
    assert wd.equilibrium_moisture(300.0, 0.0) == 0.0
    # rises with humidity, falls with temperature
    h = np.linspace(0.0, 0.95, 20)
    assert np.all(np.diff(wd.equilibrium_moisture(300.0, h)) > 0)
    assert wd.equilibrium_moisture(350.0, 0.5) < wd.equilibrium_moisture(300.0, 0.5)


# ------------------------------------------------------------------ heat capacity, enthalpy
def _handbook_heat_capacity_per_kg_dry(X, T):
    """Wood Handbook eqs. 4-18/4-19: c = (c0 + 0.01 M c_w) / (1 + 0.01 M) + A_c per kg of moist
    wood, M in percent, for wood at or below the fibre saturation point (the handbook's
    range); above it the wood at saturation plus the free water as liquid water, per kg dry."""
    c0 = 0.1031 + 0.003867 * T  # kJ/(kg K)
    Mb = min(100.0 * X, 100.0 * X_FSP)
    A_c = Mb * (-0.06191 + 2.36e-4 * T - 1.33e-4 * Mb)
    c_sat = (c0 + 0.01 * Mb * 4.186) / (1 + 0.01 * Mb) + A_c
    return 1e3 * (c_sat * (1.0 + 0.01 * Mb) + (X - 0.01 * Mb) * 4.186)


def test_heat_capacity_matches_wood_handbook_equations():
    for X in (0.0, 0.05, 0.12, 0.3, 0.6, 1.2):
        for T in (280.0, 330.0, 370.0):
            assert wd.heat_capacity(X, T, X_FSP) == pytest.approx(
                _handbook_heat_capacity_per_kg_dry(X, T), rel=1e-3), (X, T)
    # dry wood at 20 °C: about 1.2 kJ/(kg K)
    assert wd.heat_capacity(0.0, 293.15, X_FSP) == pytest.approx(1237.0, rel=1e-2)


@pytest.mark.parametrize("X", [0.0, 0.08, 0.2, 0.29, 0.31, 0.6, 1.3])
def test_heat_capacity_is_the_temperature_derivative_of_enthalpy(X):
    for T in (280.0, 320.0, 360.0, 400.0):
        h = 1e-3
        dh_dT = (wd.enthalpy(X, T + h, X_FSP) - wd.enthalpy(X, T - h, X_FSP)) / (2 * h)
        assert wd.heat_capacity(X, T, X_FSP) == pytest.approx(dh_dT, rel=1e-8), (X, T)


def test_enthalpy_reference_and_heat_of_sorption():
    # reference: dry fibre at 0 °C has zero enthalpy; above the fibre saturation point
    # adding water at 0 °C adds nothing (liquid water's reference)
    assert wd.enthalpy(0.0, T0, X_FSP) == 0.0
    assert wd.enthalpy(0.8, T0, X_FSP) == pytest.approx(wd.enthalpy(0.4, T0, X_FSP), abs=1e-6)
    # below it, dh/dX at 0 °C is minus the differential heat of sorption (module notes)
    for X in (0.02, 0.1, 0.2, 0.28):
        dh_dX = (wd.enthalpy(X + 1e-7, T0, X_FSP) - wd.enthalpy(X - 1e-7, T0, X_FSP)) / 2e-7
        assert -dh_dX == pytest.approx(wd.sorption_heat(X, X_FSP), rel=1e-5), X
    # Stanish et al.: 40 % of h_fg at zero moisture, nothing at the fibre saturation point
    assert wd.sorption_heat(0.0, X_FSP) == pytest.approx(0.4 * H_FG0)
    assert wd.sorption_heat(X_FSP, X_FSP) == 0.0
    # free water adds the heat of liquid water and nothing else (the bond adjustment belongs
    # to the bound water)
    T = 350.0
    d = (wd.enthalpy(0.9, T, X_FSP) - wd.enthalpy(0.5, T, X_FSP)) / 0.4
    assert d == pytest.approx(C_W * (T - T0), rel=1e-9)


# ------------------------------------------------------------------ drying-rate reduction
def test_drying_reduction_shape():
    X_cr, w_cr, alpha_b, w_eq = 1.25, 0.12, 0.0011, 0.10
    X = np.linspace(0.0, 2.5, 251)
    a = wd.drying_reduction(X, 0.05, X_cr, w_cr, alpha_b, w_eq)
    assert np.all(np.diff(a) >= 0.0)  # more water never dries slower
    assert wd.drying_reduction(0.05, 0.05, X_cr, w_cr, alpha_b, w_eq) == 0.0  # equilibrium
    assert np.all(a[X < 0.05] < 0.0)  # over-dried fibre re-adsorbs
    assert a[-1] == pytest.approx(1.0, abs=1e-4)  # free water
    # bound-water regime: alpha_b once the free-water sigmoid and the equilibrium ramp are
    # both far away (a narrow sigmoid makes that happen within the range)
    mid = wd.drying_reduction(0.7, 0.05, X_cr, 0.02, alpha_b, w_eq)
    assert mid == pytest.approx(alpha_b, rel=1e-4)
    assert wd.drying_reduction(X_cr, 0.05, X_cr, w_cr, alpha_b, w_eq) == pytest.approx(
        0.5 * (1.0 + alpha_b), rel=1e-6)  # half-way at the critical moisture


# ------------------------------------------------------------------ scalar and array calls
@pytest.mark.parametrize("fn", [
    lambda X: wd.heat_capacity(X, 340.0, X_FSP),
    lambda X: wd.enthalpy(X, 340.0, X_FSP),
    lambda X: wd.sorption_heat(X, X_FSP),
    lambda X: wd.drying_reduction(X, 0.05, 1.25, 0.12, 0.0011, 0.1),
    lambda h: wd.equilibrium_moisture(330.0, h),
])
def test_each_function_takes_a_scalar_and_an_array(fn, scalar_and_array):
    scalar_and_array(fn, [0.05, 0.25, 0.9])
