"""The plant family: the structure of one independent plant, drawn from its plant seed.

Every number here is a property of the plant (its fibre, its burner, its walls, its
instruments), not of a day: two day seeds of one plant seed share all of it. The draws are
uniform in the ranges listed in the package docstring, from ``numpy.random.default_rng(
[plant_seed, 0xD27E, attempt])``, in a fixed order, so a plant seed always gives the same member.
:func:`draw_structure` returns the uncommissioned member; the kinetic multiplier ``kappa``
that lands the nominal outlet moisture on ``target_moisture`` is found by
:mod:`.commissioning`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.plant.independent.fibre import VARIANTS

#: Names of the temperature sensors with a first-order lag each.
LAGGED_SENSORS: tuple[str, ...] = ("T_air_in", "T_dryer_out", "T_cyclone_out", "T_fiber_in",
                                   "T_amb")


@dataclass(frozen=True)
class Structure:
    """One member of the family (units in the field comments)."""

    plant_seed: int
    # drying kinetics
    variant: str
    kinetic: dict[str, float]         # the variant's constants
    kappa: float                      # kinetic multiplier [-] (set by commissioning)
    target_moisture: float            # nominal outlet moisture aimed at [kg/kg]
    # sorption (GAB) and heat of sorption
    gab_xm: float                     # kg/kg at 298.15 K
    gab_c: float                      # -
    gab_k: float                      # -
    gab_lam: float                    # 1/K, Xm temperature coefficient
    gab_ec: float                     # K, Arrhenius term of C
    gab_ek: float                     # K, Arrhenius term of K
    q_sorp: float                     # J/kg, heat of sorption at X = 0
    x_sorp: float                     # kg/kg, its decay moisture
    # fibre and flocs
    cp_scale: float                   # dry-wood heat capacity multiplier [-]
    d_fibre: float                    # m
    rho_fibre: float                  # kg/m3 (fibre with lumen)
    floc: float                       # open share of the geometric surface [-]
    d_floc: float                     # m, volume-equivalent
    rho_floc: float                   # kg/m3 dry floc
    sphericity: float                 # -
    u_inject: float                   # m/s, fibre velocity at injection
    # hot gas and flaps
    T_hot: float                      # K, burner gas before the flaps (plant mean)
    Y_hot: float                      # kg/kg, its humidity (plant mean)
    w_co2: float                      # CO2 mass fraction of the burner's dry gas [-]
    frac_min: float                   # hot-gas fraction with the flaps shut [-]
    frac_max: float                   # ... and fully open
    flap_shape: float                 # flap characteristic exponent [-]
    dead_time: float                  # s, flaps to tube inlet
    # tube and duct walls, outside
    deposit: float                    # m, deposit thickness at mid-tube
    deposit_slope: float              # -, extra deposit at the inlet (1 + slope)
    deposit_k: float                  # W/(m K)
    solids_factor: float              # inner-h enhancement by the fibre load [-]
    emissivity: float                 # -
    wind_exposure: float              # share of the site wind the tube sees [-]
    duct_length: float                # m
    # cyclone
    t_hold: float                     # s, fibre hold-up
    leak: float                       # false air, share of the dry gas flow [-]
    u_rel: float                      # gas-strand velocity, share of the inlet velocity [-]
    cyc_area: float                   # strand open surface, share of the tube's [-]
    h_cyclone: float                  # W/(m2 K), swirling gas to the shell
    shell_share_a: float              # share of the shell beside the outer vortex [-]
    # instruments, site and feed
    sensor_tau: dict[str, float]      # s, first-order lag per temperature sensor
    wind_median: float                # m/s, site
    moisture_day_sd: float            # kg/kg, day-to-day inlet moisture
    moisture_wander_sd: float         # kg/kg, within-day wander
    moisture_wander_tau: float        # s, its correlation time

    def commissioned(self, kappa: float) -> Structure:
        return dataclasses.replace(self, kappa=float(kappa))

    def as_dict(self) -> dict[str, Any]:
        """JSON-able description for ``/truth/effect`` and benchmark printouts."""
        d = dataclasses.asdict(self)
        d.pop("plant_seed")
        return {k: (round(v, 6) if isinstance(v, float) else
                    {a: round(b, 6) for a, b in v.items()} if isinstance(v, dict) else v)
                for k, v in d.items()}


def draw_structure(plant_seed: int, attempt: int = 0) -> Structure:
    """Draw ``attempt`` of ``plant_seed`` (before commissioning: ``kappa`` = 1).

    :mod:`.commissioning` takes attempt 0 unless it cannot be commissioned into a plausible
    dryer, then attempt 1, and so on.
    """
    rng = np.random.default_rng([int(plant_seed), 0xD27E, int(attempt)])

    def u(lo: float, hi: float) -> float:
        return float(rng.uniform(lo, hi))

    variant = VARIANTS[int(rng.integers(len(VARIANTS)))]
    if variant == "rea":
        kinetic = {"b": u(5.0, 12.0), "c": u(0.8, 1.3)}
    elif variant == "cdc":
        kinetic = {"X_cr": u(1.1, 1.4), "n": u(1.0, 2.5)}
    else:
        kinetic = {"E_a": u(15e3, 40e3), "beta": u(2.5, 6.0)}
    return Structure(
        plant_seed=int(plant_seed), variant=variant, kinetic=kinetic, kappa=1.0,
        target_moisture=u(0.085, 0.12),
        gab_xm=u(0.055, 0.065), gab_c=u(6.0, 10.0), gab_k=u(0.77, 0.80),
        gab_lam=u(0.0015, 0.0025), gab_ec=u(700.0, 1300.0), gab_ek=u(150.0, 350.0),
        q_sorp=u(0.9e6, 1.2e6), x_sorp=u(0.06, 0.09),
        cp_scale=u(0.95, 1.08), d_fibre=u(30e-6, 50e-6), rho_fibre=u(400.0, 600.0),
        floc=u(0.06, 0.2), d_floc=u(1e-3, 4e-3), rho_floc=u(30.0, 100.0),
        sphericity=u(0.3, 0.7), u_inject=u(3.0, 8.0),
        T_hot=u(850.0, 1000.0), Y_hot=u(0.05, 0.12), w_co2=u(0.08, 0.16),
        frac_min=u(0.02, 0.06), frac_max=u(0.5, 0.65),
        flap_shape=float(rng.choice([-1.0, 1.0])) * u(0.3, 1.5), dead_time=u(5.0, 30.0),
        deposit=u(0.5e-3, 3e-3), deposit_slope=u(0.0, 0.6), deposit_k=u(0.08, 0.15),
        solids_factor=u(1.0, 1.4), emissivity=u(0.6, 0.9), wind_exposure=u(0.5, 1.0),
        duct_length=u(5.0, 15.0),
        t_hold=u(3.0, 20.0), leak=u(0.0, 0.03), u_rel=u(0.2, 0.5), cyc_area=u(0.005, 0.03),
        h_cyclone=u(15.0, 45.0), shell_share_a=u(0.6, 0.8),
        sensor_tau={name: u(10.0, 90.0) for name in LAGGED_SENSORS},
        wind_median=u(1.5, 5.0),
        moisture_day_sd=u(0.005, 0.015), moisture_wander_sd=u(0.001, 0.004),
        moisture_wander_tau=u(3.0, 6.0) * 3600.0,
    )
