"""Derived geometry and constants of one plant, packed for the numba kernels.

The state layout of the model is defined here and nowhere else: a state vector holds the
slow states only, ``[T_w[0..n_d-1], T_sh[0..n_c-1]]`` (tube wall cells, then cyclone shell
cells), in K. Everything else (fibre and air profiles) is a function of the state and the
window's inputs (see :mod:`softsensor.model.dryer`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softsensor.plantconfig import DRYING_LAWS, PlantConfig

# Indices into the packed geometry array ``geo`` (float64), shared with the kernels.
P, DX, D, D_OUT, A_FLOW, C_W_CELL, G_COND, S_SPEC, D_FIB, D_P, RHO_FIB = range(11)
X_FSP, X_CR, W_CR, ALPHA_B, W_EQ, T_HOT, Y_HOT, WIND, EMISS = range(11, 20)
V_C_CELL, A_SH_CELL, C_SH_CELL, H_IN_CYC, D_CYC, N_D, N_C = range(20, 27)
TAU_HOLD, R_WALL_IN, R_WALL_OUT, D_MEAN = range(27, 31)
# the drying-rate law (index into plantconfig.DRYING_LAWS) and its shape parameters
DRY_LAW, CDC_N, REA_B, REA_C = range(31, 35)
# the heat-loss law's ambient slope [1/K] (config), added to the aux's BETA_AMB
AMB_SLOPE = 35
N_GEO = 36

#: Indices into the auxiliary (model-extension) array: ``BETA_AMB`` [1/K] makes the outside
#: heat-loss coefficients grow by ``1 + BETA_AMB (T_AMB_REF - T_amb)`` (diagnosis extension;
#: the config's ``environment.ambient_loss_slope``, ``geo[AMB_SLOPE]``, adds to it).
BETA_AMB = 0
N_AUX = 1
T_AMB_REF = 283.15


@dataclass(frozen=True)
class Geometry:
    """Numbers the kernels need, derived once from a :class:`PlantConfig`."""

    n_d: int
    n_c: int
    packed: np.ndarray

    @property
    def n_state(self) -> int:
        return self.n_d + self.n_c

    @property
    def wall(self) -> slice:
        """Tube wall temperatures in a state vector."""
        return slice(0, self.n_d)

    @property
    def shell(self) -> slice:
        """Cyclone shell temperatures in a state vector."""
        return slice(self.n_d, self.n_d + self.n_c)


def geometry(cfg: PlantConfig, n_d: int | None = None) -> Geometry:
    """Derive the packed geometry of ``cfg`` (optionally with another number of tube cells)."""
    t, c, f = cfg.tube, cfg.cyclone, cfg.fiber
    n_d = int(n_d if n_d is not None else t.n_cells)
    g = np.zeros(N_GEO)
    g[P] = cfg.environment.pressure
    g[DX] = t.length / n_d
    g[D] = t.diameter
    g[D_OUT] = t.diameter + 2.0 * t.wall_thickness
    g[A_FLOW] = np.pi * t.diameter**2 / 4.0
    a_cross = np.pi * (t.diameter + t.wall_thickness) * t.wall_thickness
    g[C_W_CELL] = t.wall_density * t.wall_heat_capacity * a_cross * g[DX]
    g[G_COND] = t.wall_conductivity * a_cross / g[DX]
    g[S_SPEC] = f.specific_surface
    g[D_FIB] = f.diameter
    g[D_P] = (1.5 * f.diameter**2 * f.length) ** (1.0 / 3.0)  # volume-equivalent sphere
    g[RHO_FIB] = f.dry_density
    g[X_FSP] = f.saturation_point
    g[X_CR] = f.critical_moisture
    g[W_CR] = f.critical_width
    g[ALPHA_B] = f.bound_fraction
    g[W_EQ] = f.equilibrium_width
    g[T_HOT] = cfg.hot_gas.temperature
    g[Y_HOT] = cfg.hot_gas.humidity
    g[WIND] = cfg.environment.wind_speed
    g[EMISS] = t.wall_emissivity
    g[V_C_CELL] = c.volume / c.n_cells
    a_shell = c.count * np.pi * c.diameter * c.height
    g[A_SH_CELL] = a_shell / c.n_cells
    g[C_SH_CELL] = c.shell_density * c.shell_heat_capacity * c.shell_thickness * g[A_SH_CELL]
    g[H_IN_CYC] = c.inner_heat_transfer
    g[D_CYC] = c.diameter
    g[N_D] = n_d
    g[N_C] = c.n_cells
    g[TAU_HOLD] = c.hold_up_time
    # conduction resistance [m2 K/W] from the wall node (mid-steel) to either surface: the
    # inner side crosses the fibre deposit too
    g[R_WALL_IN] = (t.deposit_thickness / t.deposit_conductivity
                    + 0.5 * t.wall_thickness / t.wall_conductivity)
    g[R_WALL_OUT] = 0.5 * t.wall_thickness / t.wall_conductivity
    g[D_MEAN] = t.diameter + t.wall_thickness
    g[DRY_LAW] = DRYING_LAWS.index(f.drying_law)
    g[CDC_N] = f.cdc_exponent
    g[REA_B] = f.rea_b
    g[REA_C] = f.rea_c
    g[AMB_SLOPE] = cfg.environment.ambient_loss_slope
    return Geometry(n_d=n_d, n_c=c.n_cells, packed=g)
