"""Steady-state conservation: water and energy close between the dryer inlet and outlet.

At steady state, summing the cell balances of the tube and the cyclone (cell_physics module
docstring) must give: water in (fibre plus air) = water out, and enthalpy in = enthalpy out +
heat through the walls; at a steady wall that heat equals what the walls lose to ambient.
Enthalpies are recomputed here from the profiles with the property functions, independently
of how the kernels march. The model page's claim (``docs/explanation/model.md``), checked at that
tolerance: water and energy close to 1e-15 of what flows in (measured up to 6.4e-16 and 3.5e-16),
and at a steady wall the loss to ambient equals the heat the walls take to 1e-13 (measured up to
5.3e-14).
"""

from __future__ import annotations

import numpy as np
import pytest

from softsensor.model import DryerModel, cell_physics
from softsensor.model import humid_air as ha
from softsensor.model import wood as wd

#: docs/explanation/model.md: closure relative to the water and enthalpy flowing in, and of the
#wall's
#: steady heat loss against the heat it takes from the air.
CLOSURE = 1e-15
WALL_CLOSURE = 1e-13
#: The same for the alternative drying laws (test_balances_close_with_each_drying_law).
LAW_WALL_CLOSURE = 2e-6

POINTS = {
    "nominal": {},
    "hot_low_production": {"T_air_in": 520.0, "m_fiber": 5.0},
    "cold_winter_high_production": {"T_air_in": 460.0, "m_fiber": 7.0, "T_amb": 258.0,
                                    "H_amb": 0.001},
    "wet_fibre_summer": {"moisture_in": 1.3, "T_air_in": 545.0, "T_amb": 305.0,
                         "H_amb": 0.018, "m_air": 90.0},
}


def _budget(model: DryerModel, u: np.ndarray, theta: np.ndarray, aux=None):
    state, _ = model.steady_state(u, theta, aux)
    p = model.profiles(state, u, theta)
    geo = model.geometry.packed
    x_fsp = model.config.fiber.saturation_point
    m_a, m_f = u[cell_physics.U_MAIR], u[cell_physics.U_MFIB]
    Y_in, h_a_in = cell_physics.inlet_air(u, geo)
    X_in, T_f_in = u[cell_physics.U_XIN], u[cell_physics.U_TFIB]
    last = -1
    water_in = m_f * X_in + m_a * Y_in
    water_out = m_f * p["X_f"][last] + m_a * p["Y_a"][last]
    energy_in = m_f * wd.enthalpy(X_in, T_f_in, x_fsp) + m_a * h_a_in
    energy_out = (m_f * wd.enthalpy(p["X_f"][last], p["T_f"][last], x_fsp)
                  + m_a * ha.enthalpy(p["T_a"][last], p["Y_a"][last]))
    wall_in = float(np.sum(p["UA_w"] * (p["T_a_wall"] - p["T_w"])))
    aux = np.zeros(1) if aux is None else np.asarray(aux, float)
    n_d = model.geometry.n_d
    to_ambient = sum(
        cell_physics.outside_conductance(p["T_w"][i], u, theta, aux, geo, 0 if i < n_d else 1)
        * (p["T_w"][i] - u[cell_physics.U_TAMB]) for i in range(model.n_state))
    return dict(water_in=water_in, water_out=water_out, energy_in=energy_in,
                energy_out=energy_out, wall_in=wall_in, to_ambient=to_ambient,
                evaporated=m_f * (X_in - p["X_f"][last]), profiles=p)


@pytest.mark.parametrize("point", sorted(POINTS))
def test_water_closes(model, point):
    b = _budget(model, model.nominal_inputs(**POINTS[point]), model.theta0)
    assert b["water_out"] == pytest.approx(b["water_in"], rel=CLOSURE, abs=0)
    # the check has teeth: the fibre really dried, the air really took the water
    assert b["evaporated"] > 0.3 * model.nominal_inputs(**POINTS[point])[cell_physics.U_MFIB]


@pytest.mark.parametrize("point", sorted(POINTS))
def test_energy_closes_counting_the_wall_heat_loss(model, point):
    b = _budget(model, model.nominal_inputs(**POINTS[point]), model.theta0)
    # energy in = energy out + heat through the walls, to 0.5 % of the energy that flows
    assert b["energy_in"] - b["energy_out"] == pytest.approx(
        b["wall_in"], abs=5e-3 * b["energy_in"])
    # in fact to round-off of the enthalpy flow: the march conserves enthalpy cell by cell
    assert b["energy_in"] - b["energy_out"] == pytest.approx(
        b["wall_in"], rel=0, abs=CLOSURE * b["energy_in"])
    # the wall loss is real (a bare 55 m tube and two cyclones lose 100 kW to 1 MW) ...
    assert 1e5 < b["wall_in"] < 1e6
    # ... and at a steady wall it all leaves to ambient (axial conduction only moves it)
    assert b["to_ambient"] == pytest.approx(b["wall_in"], rel=WALL_CLOSURE, abs=0)


def test_balances_close_with_other_parameters_and_the_ambient_extension(model):
    theta = model.theta0 * np.array([2.0, 0.5, 0.5, 3.0, 2.5, 4.0, 0.3])
    b = _budget(model, model.nominal_inputs(T_amb=265.0), theta, aux=np.array([0.02]))
    assert b["water_out"] == pytest.approx(b["water_in"], rel=CLOSURE, abs=0)
    assert b["energy_in"] - b["energy_out"] == pytest.approx(
        b["wall_in"], rel=0, abs=CLOSURE * b["energy_in"])
    assert b["to_ambient"] == pytest.approx(b["wall_in"], rel=WALL_CLOSURE, abs=0)
    assert b["to_ambient"] == pytest.approx(b["wall_in"], rel=WALL_CLOSURE, abs=0)


def test_each_cell_conserves_water_and_energy(model):
    # per-cell form: water and enthalpy carried by fibre plus air change only by the heat
    # that cell gives to its wall
    u = model.nominal_inputs()
    b = _budget(model, u, model.theta0)
    p = b["profiles"]
    x_fsp = model.config.fiber.saturation_point
    m_a, m_f = u[cell_physics.U_MAIR], u[cell_physics.U_MFIB]
    water = m_f * p["X_f"] + m_a * p["Y_a"]
    np.testing.assert_allclose(water, b["water_in"], rtol=1e-9)
    flow = m_f * wd.enthalpy(p["X_f"], p["T_f"], x_fsp) + m_a * ha.enthalpy(p["T_a"], p["Y_a"])
    lost = np.cumsum(p["UA_w"] * (p["T_a_wall"] - p["T_w"]))
    np.testing.assert_allclose(flow + lost, b["energy_in"], rtol=1e-9)


def test_physical_profile(model):
    # air cools and takes up water along the tube; the fibre dries; humid air stays below
    # saturation; the outlet is in the published MDF-dryer envelope (STACK.md)
    p = _budget(model, model.nominal_inputs(), model.theta0)["profiles"]
    n_d = model.geometry.n_d
    assert np.all(np.diff(p["T_a"][:n_d]) < 0)
    assert np.all(np.diff(p["Y_a"]) >= 0)
    assert np.all(np.diff(p["X_f"]) <= 0)
    assert np.all(p["Y_a"] < ha.y_sat(p["T_a"], model.config.environment.pressure))
    assert 339.0 < p["T_a"][n_d - 1] < 361.0  # 66 to 88 °C
    assert 0.06 < p["X_f"][-1] < 0.16


def test_humid_air_condenses_on_cold_wet_fibre(model):
    """The tube's evaporation follows the sign of its driving force: air more humid than
    saturation at the fibre surface gives water to fibre that is far above equilibrium (a
    rate taken by magnitude would dry it)."""
    geo, theta = model.geometry.packed, model.theta0
    P = geo[cell_physics.P]
    Tf, Ta = 300.0, 420.0
    wet = ha.y_sat(Tf, P)
    R_cond, *_ = cell_physics.cell_rates(0, 1.0, Tf, 1.5 * wet, Ta, 1.0, 80.0, 6.0, theta, geo)
    R_evap, *_ = cell_physics.cell_rates(0, 1.0, Tf, 0.5 * wet, Ta, 1.0, 80.0, 6.0, theta, geo)
    assert R_cond < 0.0 < R_evap


@pytest.fixture(scope="module")
def law_models(config):
    """A model per alternative drying law, commissioned as the structural library says."""
    from softsensor.model.structure import alternative_config, structure_space

    return {a.sets["fiber.drying_law"]: DryerModel(alternative_config(config, a))
            for a in structure_space()
            if a.family == "drying_law" and not a.default}


@pytest.mark.parametrize("law", ["cdc", "rea"])
@pytest.mark.parametrize("point", sorted(POINTS))
def test_balances_close_with_each_drying_law(law_models, law, point):
    # the laws change the rate R, which enters the fibre and the air alike: water and energy
    # close as for the paper's law (measured: as tight). The wall's steady loss against the
    # heat it takes closes less tightly where a law brings the fibre to its equilibrium
    # moisture in the tube with the air above 110 C (cdc, hot_low_production: 6.0e-7;
    # rea, cold_winter: 2.6e-13; every other case below 1e-13): the equilibrium moisture's
    # temperature clamp (wood.equilibrium_moisture) is a kink in the cell residual there, and
    # the steady wall iteration stops at a profile a cell's Newton left off its root (with the
    # clamp moved to 125 C, as an experiment, 2.4e-10)
    m = law_models[law]
    u = m.nominal_inputs(**POINTS[point])
    b = _budget(m, u, m.theta0)
    assert b["water_out"] == pytest.approx(b["water_in"], rel=CLOSURE, abs=0)
    assert b["energy_in"] - b["energy_out"] == pytest.approx(
        b["wall_in"], rel=0, abs=CLOSURE * b["energy_in"])
    assert b["to_ambient"] == pytest.approx(b["wall_in"], rel=LAW_WALL_CLOSURE, abs=0)
    assert b["evaporated"] > 0.3 * u[cell_physics.U_MFIB]
