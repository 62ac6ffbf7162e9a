"""The independent plant's process: flaps and mixing, tube, duct, cyclone, walls.

:class:`Process` holds one family member with the reference plant's geometry (``config.tube``,
``config.cyclone``, ``config.environment.pressure``) and its wall and shell temperatures.
:meth:`Process.instant` solves the flow at one instant (:mod:`.chain`), :meth:`Process.advance`
moves the walls on, :meth:`Process.steady` finds the steady state for constant inputs.

Hot gas and flaps: the flap position ``pos`` [%] sets the burner gas share of the dry gas
through a nonlinear characteristic ``frac = f_min + (f_max - f_min) c(pos / 100)``,
``c(x) = (exp(a x) - 1) / (exp(a) - 1)`` (equal-percentage for ``a > 0``, quick-opening for
``a < 0``; Driskell, *Control-Valve Selection and Sizing*, 1983, ch. 5); the burner gas
(temperature, humidity, CO2 share) mixes adiabatically with ambient air. The fan flow
``m_air`` is the dry-gas flow through the tube.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsensor.errors import SolverError
from softsensor.plant.independent import chain, step
from softsensor.plant.independent.cyclone import shell_areas
from softsensor.plant.independent.family import Structure
from softsensor.plant.independent.fibre import VARIANTS
from softsensor.plant.independent.layout import (
    MODE_TUBE,
    new_parameters,
)
from softsensor.plant.independent.properties import burner_mix, temperature_of
from softsensor.plant.independent.transfer import (
    entry_factor,
    haider_levenspiel_constants,
)
from softsensor.plant.independent.wall import (
    N_WCOL,
    W_AREA,
    W_C_DEP,
    W_C_STEEL,
    W_DIAM,
    W_EMIS,
    W_R_DEP,
    W_WIND,
)
from softsensor.plantconfig import PlantConfig

N_TUBE_SEGMENTS = 22
N_DUCT_SEGMENTS = 2
RISER_LENGTH = 30.0          # m of the tube that rise vertically from the injection
DEPOSIT_RHO_CP = 350.0 * 1800.0  # J/(m3 K), fibre-resin cake


@dataclass
class Inputs:
    """True process inputs at one instant (SI)."""

    m_fiber: float      # kg/s dry
    X_in: float         # kg/kg
    T_fiber_in: float   # K
    m_steam: float      # kg/s
    m_gas: float        # kg/s dry gas through the tube (fan)
    e_gas: float        # J/kg dry gas, tube inlet gas enthalpy
    Y_gas: float        # kg/kg
    w_co2: float        # CO2 mass fraction of the dry gas [-]
    T_amb: float        # K
    H_amb: float        # kg/kg
    wind: float         # m/s at the site
    cloud: float        # cloud cover [0..1]
    xfer: float = 1.0        # tube gas-fibre transfer multiplier (fouling, chip batch)
    surface: float = 1.0     # fibre surface multiplier (chip batch) in the cyclone
    kappa_mult: float = 1.0  # kinetic multiplier (chip batch)
    loss_mult: float = 1.0   # outside heat-loss multiplier (ambient effect)

    def array(self) -> np.ndarray:
        """The inputs in the compiled layout (``chain.U_*``)."""
        return np.array([self.m_fiber, self.X_in, self.T_fiber_in, self.m_steam, self.m_gas,
                         self.e_gas, self.Y_gas, self.w_co2, self.T_amb, self.H_amb, self.wind,
                         self.cloud, self.xfer, self.surface, self.kappa_mult, self.loss_mult])


@dataclass
class Instant:
    """The flow solved at one instant (copies of the compiled outputs)."""

    out: np.ndarray      # chain.O_*
    q_seg: np.ndarray    # W per wall segment
    s_seg: np.ndarray    # W/K per wall segment
    profile: np.ndarray  # state at each segment's end (chain.PROFILE_COLUMNS)
    u: np.ndarray        # the inputs (chain.U_*)

    def __getattr__(self, name: str) -> float:
        if name.startswith("O_"):
            return float(self.out[getattr(chain, name)])
        raise AttributeError(name)

    @property
    def T_dryer_out(self) -> float:
        return float(self.out[chain.O_TG_TUBE])

    @property
    def T_cyclone_out(self) -> float:
        return float(self.out[chain.O_T_CYC])

    @property
    def moisture_out(self) -> float:
        return float(self.out[chain.O_X_OUT])

    @property
    def moisture_tube_out(self) -> float:
        return float(self.out[chain.O_X_TUBE])


class Process:
    """One family member in the reference plant's geometry, with its wall states."""

    def __init__(self, structure: Structure, config: PlantConfig) -> None:
        self.structure = st = structure
        tube, cyc = config.tube, config.cyclone
        self.pressure = float(config.environment.pressure)
        self.diameter = float(tube.diameter)
        self.area = math.pi * self.diameter ** 2 / 4.0
        self.n_tube = N_TUBE_SEGMENTS
        n_seg = N_TUBE_SEGMENTS + N_DUCT_SEGMENTS
        self.seg = np.zeros((n_seg, chain.N_SCOL))
        self.walls = np.zeros((n_seg, N_WCOL))
        dz = tube.length / N_TUBE_SEGMENTS
        dd = st.duct_length / N_DUCT_SEGMENTS
        c_steel = tube.wall_density * tube.wall_heat_capacity * tube.wall_thickness
        for j in range(n_seg):
            in_tube = j < N_TUBE_SEGMENTS
            length = dz if in_tube else dd
            z_mid = (j + 0.5) * dz if in_tube else tube.length + (j - self.n_tube + 0.5) * dd
            self.seg[j, chain.S_LEN] = length
            self.seg[j, chain.S_HI] = entry_factor(z_mid, self.diameter) * st.solids_factor
            self.seg[j, chain.S_GEFF] = 9.80665 if z_mid < RISER_LENGTH else 0.0
            frac = min(z_mid / tube.length, 1.0)
            delta = st.deposit * (1.0 + st.deposit_slope * (1.0 - 2.0 * frac))
            self.walls[j, W_AREA] = math.pi * self.diameter * length
            self.walls[j, W_C_DEP] = DEPOSIT_RHO_CP * delta
            self.walls[j, W_R_DEP] = delta / st.deposit_k + 0.5 * tube.wall_thickness \
                / tube.wall_conductivity
            self.walls[j, W_C_STEEL] = c_steel
            self.walls[j, W_DIAM] = self.diameter + 2.0 * tube.wall_thickness
            self.walls[j, W_EMIS] = st.emissivity
            self.walls[j, W_WIND] = st.wind_exposure
        area_total, _ = shell_areas(cyc.diameter, cyc.height, cyc.volume, cyc.count)
        self.shell_area = (st.shell_share_a * area_total, (1.0 - st.shell_share_a) * area_total)
        self.shell_c = cyc.shell_density * cyc.shell_heat_capacity * cyc.shell_thickness
        self.cyclone_diameter = float(cyc.diameter)
        self.z_end = np.cumsum(self.seg[:, chain.S_LEN])  # m, each segment's end
        self.p_base = self._base_parameters()
        self.k_const = self._member_constants()
        self.sh = np.zeros(step.N_SH)
        self.sh[step.SH_AREA_A], self.sh[step.SH_AREA_B] = self.shell_area
        self.sh[step.SH_UA_A] = st.h_cyclone * self.shell_area[0]
        self.sh[step.SH_C_AREA] = self.shell_c
        self.sh[step.SH_DIAM] = self.cyclone_diameter
        self.sh[step.SH_EMIS] = st.emissivity
        self.sh[step.SH_WIND] = st.wind_exposure
        self.Td = np.full(n_seg, 330.0)
        self.Ts = np.full(n_seg, 320.0)
        self.T_shell = np.array([330.0, 330.0])

    # -- parameters -----------------------------------------------------------------------
    def _base_parameters(self) -> np.ndarray:
        st = self.structure
        hl = haider_levenspiel_constants(st.sphericity)
        k = st.kinetic
        if st.variant == "rea":
            ka, kb, kc = k["b"], k["c"], 0.0
        elif st.variant == "cdc":
            ka, kb, kc = k["X_cr"], k["n"], 0.0
        else:
            ka, kb, kc = 1.0, k["E_a"], k["beta"]
        return new_parameters(
            variant=float(VARIANTS.index(st.variant)), kappa=st.kappa, k_a=ka, k_b=kb, k_c=kc,
            gab_xm=st.gab_xm, gab_c=st.gab_c, gab_k=st.gab_k, gab_lam=st.gab_lam,
            gab_ec=st.gab_ec, gab_ek=st.gab_ek, q_sorp=st.q_sorp, x_sorp=st.x_sorp,
            cp_scale=st.cp_scale, a_geo=4.0 / (st.rho_fibre * st.d_fibre), floc=st.floc,
            d_fibre=st.d_fibre, d_floc=st.d_floc, rho_floc=st.rho_floc,
            hl_a=hl[0], hl_b=hl[1], hl_c=hl[2], hl_d=hl[3], pressure=self.pressure,
            diameter=self.diameter, area=self.area, mode=MODE_TUBE, xfer=1.0)

    def _member_constants(self) -> np.ndarray:
        st = self.structure
        k = np.zeros(chain.N_K)
        k[chain.K_KAPPA] = st.kappa
        k[chain.K_U_INJECT] = st.u_inject
        k[chain.K_T_HOLD] = st.t_hold
        k[chain.K_U_REL] = st.u_rel
        k[chain.K_CYC_AREA] = st.cyc_area
        k[chain.K_UA_A] = st.h_cyclone * self.shell_area[0]
        k[chain.K_UA_B] = st.h_cyclone * self.shell_area[1]
        k[chain.K_LEAK] = st.leak
        return k

    def set_kappa(self, kappa: float) -> None:
        """Replace the kinetic multiplier (commissioning)."""
        self.structure = self.structure.commissioned(kappa)
        self.k_const[chain.K_KAPPA] = kappa

    # -- flaps and mixing -----------------------------------------------------------------
    def hot_fraction(self, pos: float) -> float:
        """Burner-gas share of the dry gas [-] at flap position ``pos`` [%]."""
        st = self.structure
        x = min(max(pos / 100.0, 0.0), 1.0)
        a = st.flap_shape
        return st.frac_min + (st.frac_max - st.frac_min) * math.expm1(a * x) / math.expm1(a)

    def flap_position(self, frac: float) -> float:
        """Inverse of :meth:`hot_fraction`, clipped to 0..100 %."""
        st = self.structure
        c = (frac - st.frac_min) / (st.frac_max - st.frac_min)
        c = min(max(c, 0.0), 1.0)
        a = st.flap_shape
        return 100.0 * math.log1p(c * math.expm1(a)) / a

    def mixed_gas(self, frac: float, T_hot: float, Y_hot: float, T_amb: float, H_amb: float
                  ) -> tuple[float, float, float]:
        """Enthalpy [J/kg dry], humidity [kg/kg] and CO2 share [-] of burner gas mixed with
        ambient air at hot-gas share ``frac``."""
        return burner_mix(frac, T_hot, Y_hot, self.structure.w_co2, T_amb, H_amb)

    @staticmethod
    def gas_temperature(e: float, Y: float, w_co2: float) -> float:
        """Temperature [K] of gas with enthalpy ``e`` [J/kg dry], humidity and CO2 share."""
        return temperature_of(e, Y, w_co2)

    # -- one instant ----------------------------------------------------------------------
    def instant(self, u: Inputs | np.ndarray, tol_scale: float = 1.0) -> Instant:
        """Solve the flow through tube, duct and cyclone at the current wall temperatures
        for inputs ``u`` (or their ``chain.U_*`` array); ``tol_scale`` multiplies the march
        tolerances."""
        ua = u.array() if isinstance(u, Inputs) else u
        n = self.seg.shape[0]
        q_seg = np.empty(n)
        s_seg = np.empty(n)
        out = np.zeros(chain.N_OUT)
        prof = np.zeros((n, len(chain.PROFILE_COLUMNS)))
        chain.solve(self.p_base, ua, self.k_const, self.T_shell, self.seg, self.n_tube,
                    self.Td, q_seg, s_seg, prof, out, tol_scale)
        if out[chain.O_STATUS] != 0:
            raise SolverError(
                f"independent plant: flow march failed (status {int(out[chain.O_STATUS])}) "
                f"at m_fiber={ua[chain.U_M_FIBER]:.4g}, X_in={ua[chain.U_X_IN]:.4g}, "
                f"m_gas={ua[chain.U_M_GAS]:.4g}, T_gas="
                f"{temperature_of(ua[chain.U_E_GAS], ua[chain.U_Y_GAS], ua[chain.U_W_CO2]):.5g}")
        return Instant(out, q_seg, s_seg, prof, ua)

    # -- walls ----------------------------------------------------------------------------
    def advance(self, res: Instant, dt: float) -> dict[str, float]:
        """Move walls and shells on by ``dt`` [s] (``dt <= 0``: to their steady state) given
        the flow ``res``; returns the losses to the surroundings [W]."""
        losses = np.empty(step.N_L)
        step.advance_all(res.u, res.out, res.q_seg, res.s_seg, self.n_tube, self.Td, self.Ts,
                         self.walls, self.T_shell, self.sh, dt, losses)
        return {"tube": float(losses[step.L_TUBE]), "duct": float(losses[step.L_DUCT]),
                "shell_a": float(losses[step.L_SHELL_A]),
                "shell_b": float(losses[step.L_SHELL_B])}

    def steady(self, u: Inputs, tol: float = 1e-5, tol_scale: float = 1e-3,
               max_iter: int = 200) -> tuple[Instant, dict[str, float]]:
        """Steady state for constant inputs ``u``: flow and walls iterated until no wall
        temperature moves by more than ``tol`` [K], with the march tolerances scaled by
        ``tol_scale`` (the iteration cannot settle below the march's own jitter)."""
        change = math.inf
        fine = False  # coarse march while the walls move a lot, then fine for good
        for _ in range(max_iter):
            before = self.wall_state()
            fine = fine or change < 1e-2
            res = self.instant(u, tol_scale if fine else 1.0)
            losses = self.advance(res, 0.0)
            change = float(np.abs(self.wall_state() - before).max())
            if change < tol:
                return res, losses
        raise SolverError(f"independent plant: walls did not settle within {max_iter} "
                          f"iterations (last change {change:.3g} K)")

    def wall_state(self) -> np.ndarray:
        return np.concatenate([self.Td, self.Ts, self.T_shell])

    def set_wall_state(self, state: np.ndarray) -> None:
        n = self.seg.shape[0]
        self.Td[:] = state[:n]
        self.Ts[:] = state[n:2 * n]
        self.T_shell[:] = state[2 * n:]

