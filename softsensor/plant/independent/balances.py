"""Water and energy books of the independent plant at steady state.

For constant inputs the plant settles (flow solved, walls and shells at their steady
temperatures); :func:`steady_balances` then lists every stream crossing the plant's
boundary: burner gas and ambient air into the flaps, fibre and steam at the injection,
false air into the cyclones, gas and fibre leaving, and the heat the tube, duct and cyclone
shells lose to the surroundings. Enthalpies refer to 273.15 K with the dry-gas species,
dry wood and *liquid* water at zero there (vapour carries its latent heat). Closure is
``|in - out| / in``; the flow march conserves both exactly by construction (the gas state is
computed from the conserved totals), so what is left is the walls' steady-state iteration
(tolerance 1e-6 K): below 1e-9 for energy, rounding (1e-15) for water (measured over the family in
``tests/plant/independent/test_independent_plant.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from softsensor.plant.independent import chain
from softsensor.plant.independent.commissioning import (
    Commissioned,
    commissioned_member,
    nominal_inputs,
)
from softsensor.plant.independent.fibre import fibre_enthalpy
from softsensor.plant.independent.process import Process
from softsensor.plant.independent.properties import (
    CP_AIR,
    dry_gas_coefficients,
    gas_enthalpy,
    h_vapour,
)
from softsensor.plantconfig import PlantConfig


@dataclass(frozen=True)
class Balances:
    """Flows across the plant boundary at steady state: water [kg/s], energy [W]."""

    water_in: dict[str, float] = field(default_factory=dict)
    water_out: dict[str, float] = field(default_factory=dict)
    energy_in: dict[str, float] = field(default_factory=dict)
    energy_out: dict[str, float] = field(default_factory=dict)
    state: dict[str, float] = field(default_factory=dict)

    @staticmethod
    def _closure(a: dict[str, float], b: dict[str, float]) -> float:
        total_in = sum(a.values())
        return abs(total_in - sum(b.values())) / abs(total_in)

    @property
    def water_closure(self) -> float:
        """Relative imbalance of the water books [-]."""
        return self._closure(self.water_in, self.water_out)

    @property
    def energy_closure(self) -> float:
        """Relative imbalance of the energy books [-]."""
        return self._closure(self.energy_in, self.energy_out)


def steady_balances(config: PlantConfig, plant_seed: int = 0, *,
                    member: Commissioned | None = None, hot_gas_share: float | None = None,
                    **overrides: float) -> Balances:
    """Settle the plant for constant inputs and return its water and energy books.

    The inputs are the nominal point of :mod:`.commissioning` (commissioned hot-gas share);
    ``hot_gas_share`` [-] and any field of :class:`.process.Inputs` given as a keyword
    (``m_fiber=5.0``, ``T_amb=265.0``, ...) override it. ``member`` replaces the
    commissioned member of ``plant_seed`` (e.g. with another ``leak``).
    """
    member = member or commissioned_member(plant_seed, config)
    process = Process(member.structure, config)
    st = process.structure
    frac = member.nominal["hot_gas_share"] if hot_gas_share is None else hot_gas_share
    u = nominal_inputs(process, config, frac)
    for name, value in overrides.items():
        if not hasattr(u, name):
            raise TypeError(f"unknown input {name!r}")
        setattr(u, name, float(value))
    e_gas, Y_gas, w = process.mixed_gas(frac, st.T_hot, st.Y_hot, u.T_amb, u.H_amb)
    u.e_gas, u.Y_gas, u.w_co2 = e_gas, Y_gas, w
    res, losses = process.steady(u, tol=1e-6, tol_scale=1e-3)
    o = res.out
    p = process.p_base
    g_hot = frac * u.m_gas
    g_amb = (1.0 - frac) * u.m_gas
    g_leak = st.leak * u.m_gas
    water_in = {"burner_gas": g_hot * st.Y_hot, "ambient_air": g_amb * u.H_amb,
                "fibre": u.m_fiber * u.X_in, "steam": u.m_steam, "leak_air": g_leak * u.H_amb}
    water_out = {"gas": o[chain.O_M_CYC] * o[chain.O_Y_CYC],
                 "fibre": u.m_fiber * o[chain.O_X_OUT]}
    e_amb = gas_enthalpy(CP_AIR, u.T_amb, u.H_amb)
    energy_in = {"burner_gas": g_hot * gas_enthalpy(dry_gas_coefficients(st.w_co2), st.T_hot,
                                                     st.Y_hot),
                 "ambient_air": g_amb * e_amb,
                 "fibre": u.m_fiber * fibre_enthalpy(u.T_fiber_in, u.X_in, p),
                 "steam": u.m_steam * h_vapour(u.T_fiber_in),
                 "leak_air": g_leak * e_amb}
    energy_out = {"gas": o[chain.O_M_CYC] * o[chain.O_E_CYC],
                  "fibre": u.m_fiber * o[chain.O_EF_OUT],
                  "tube_wall": losses["tube"], "duct_wall": losses["duct"],
                  "cyclone_shell_a": losses["shell_a"], "cyclone_shell_b": losses["shell_b"]}
    state = {"T_air_in": process.gas_temperature(u.e_gas, u.Y_gas, u.w_co2),
             "T_dryer_out": res.T_dryer_out, "T_cyclone_out": res.T_cyclone_out,
             "moisture_tube_out": res.moisture_tube_out, "moisture_out": res.moisture_out,
             "gas_heat_to_walls": float(res.q_seg.sum())}
    return Balances(water_in, water_out, energy_in, energy_out, state)
