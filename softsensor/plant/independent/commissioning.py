"""Commissioning: make a drawn family member a dryer that meets its design point.

A real dryer is designed and tuned to meet its target; so is each family member. At the
nominal point (``config.nominal``: 6 kg/s fibre at 1.0 kg/kg, 82 kg/s air, ``T_sp`` 348 K, the
member's burner gas, the site's median wind) the kinetic multiplier ``kappa`` of the drawn
kinetics law is scaled so that the steady outlet moisture, with the hot-gas share that
holds ``T_dryer_out`` at ``T_sp``, lands on the member's drawn target (0.085 to 0.12 kg/kg).
That is the only constant set this way; every other one is as drawn.

A member is accepted when the nominal ``T_air_in`` lies within 450 to 550 K, the flaps sit
between 10 and 90 % and fibre still holding free water (above 0.3 kg/kg) stays below 373 K
(water in the lumens would boil); otherwise the next draw of the same plant seed is taken
(``attempt`` in :func:`softsensor.plant.independent.family.draw_structure`), so a plant seed
still names one member.

The search is nested: for a ``kappa``, a secant search on the hot-gas share finds
``T_dryer_out = T_sp``; Brent's method on ``ln kappa`` finds the target moisture. The walls
are held at a steady state while searching and re-settled between rounds (they move the
answer by a few tenths of a kelvin at most), three rounds at most.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import brentq

from softsensor.errors import SolverError
from softsensor.plant.independent.family import Structure, draw_structure
from softsensor.plant.independent.process import Inputs, Instant, Process
from softsensor.plantconfig import PlantConfig

KAPPA_RANGE = (1e-3, 1e3)
T_AIR_IN_RANGE = (450.0, 550.0)  # K, accepted nominal inlet temperatures
FLAP_RANGE = (10.0, 90.0)        # %, accepted nominal flap positions
T_BOIL_WET = 373.0               # K, fibre above WET kg/kg holds free water: no hotter
WET = 0.3                        # kg/kg, about the fibre saturation point
MAX_ATTEMPTS = 20


class Unreachable(SolverError):
    """The flaps cannot hold the outlet temperature (``too_hot``: even when shut)."""

    def __init__(self, message: str, too_hot: bool) -> None:
        super().__init__(message)
        self.too_hot = too_hot


@dataclass(frozen=True)
class Commissioned:
    """A commissioned family member and its nominal point."""

    structure: Structure
    nominal: dict[str, float]     # T_air_in, moisture_out, ... at the nominal point
    attempt: int                  # which draw of the plant seed was accepted

    def describe(self) -> dict[str, Any]:
        return {**self.structure.as_dict(), "attempt": self.attempt,
                "nominal": {k: round(v, 6) for k, v in self.nominal.items()}}


def nominal_inputs(process: Process, config: PlantConfig, frac: float) -> Inputs:
    """The nominal operating point with hot-gas share ``frac``."""
    st = process.structure
    nom = config.nominal
    e, Y, w = process.mixed_gas(frac, st.T_hot, st.Y_hot, nom.T_amb, nom.H_amb)
    return Inputs(m_fiber=nom.m_fiber, X_in=nom.moisture_in, T_fiber_in=nom.T_fiber_in,
                  m_steam=nom.m_steam, m_gas=nom.m_air, e_gas=e, Y_gas=Y, w_co2=w,
                  T_amb=nom.T_amb, H_amb=nom.H_amb, wind=st.wind_median, cloud=0.5)


def share_for_outlet(process: Process, make: Any, T_target: float, frac0: float,
                     tol_scale: float = 1e-2) -> tuple[float, Instant]:
    """Hot-gas share [-] whose flow (walls held) gives ``T_dryer_out = T_target`` [K].

    ``make(frac)`` builds the inputs. Secant steps from ``frac0``, falling back to Brent's
    method over the flaps' whole range.
    """
    st = process.structure

    def err(f: float) -> tuple[float, Instant]:
        res = process.instant(make(f), tol_scale)
        return res.T_dryer_out - T_target, res

    f0 = min(max(frac0, st.frac_min), st.frac_max)
    e0, r0 = err(f0)
    f1 = min(max(f0 + 0.02, st.frac_min), st.frac_max)
    if f1 == f0:
        f1 = f0 - 0.02
    e1, r1 = err(f1)
    for _ in range(12):
        if abs(e1) < 1e-6:
            return f1, r1
        if e1 == e0:
            break
        f2 = f1 - e1 * (f1 - f0) / (e1 - e0)
        if not st.frac_min <= f2 <= st.frac_max:
            break
        f0, e0 = f1, e1
        f1 = f2
        e1, r1 = err(f1)
    lo, hi = st.frac_min, st.frac_max
    e_lo, e_hi = err(lo)[0], err(hi)[0]
    if e_lo > 0 or e_hi < 0:
        raise Unreachable(f"independent plant {st.plant_seed}: the flaps cannot reach "
                          f"T_dryer_out = {T_target:.2f} K", too_hot=e_lo > 0)
    f = brentq(lambda x: err(x)[0], lo, hi, xtol=1e-10)
    return f, err(f)[1]


def operating_point(process: Process, make: Any, T_target: float, frac0: float
                    ) -> tuple[float, Instant]:
    """Steady state (walls settled) whose ``T_dryer_out`` is ``T_target`` [K]: the hot-gas
    share and the flow; ``make(frac)`` builds the inputs."""
    frac = frac0
    for _ in range(20):
        process.steady(make(frac))
        new, res = share_for_outlet(process, make, T_target, frac, tol_scale=1e-3)
        if abs(new - frac) < 1e-9:
            return new, res
        frac = new
    raise SolverError(f"independent plant {process.structure.plant_seed}: no steady "
                      f"operating point at T_dryer_out = {T_target:.2f} K")


def commission(structure: Structure, config: PlantConfig) -> tuple[Structure, dict[str, float]]:
    """Find ``kappa`` for the member's target moisture; returns the commissioned structure
    and its nominal point (raises SolverError when the target cannot be met)."""
    target = structure.target_moisture
    T_sp = config.nominal.T_sp
    log_k = 0.0
    frac = 0.25
    process = Process(structure, config)
    def moisture(lk: float, walls: np.ndarray) -> float:
        nonlocal frac
        process.set_kappa(math.exp(lk))
        process.set_wall_state(walls)
        try:
            frac, res = share_for_outlet(
                process, lambda f: nominal_inputs(process, config, f), T_sp, frac)
        except Unreachable as exc:
            if exc.too_hot:  # kinetics so slow the shut flaps still overheat: too wet
                return 1.0
            raise
        return res.moisture_out - target

    for _ in range(3):
        process.steady(nominal_inputs(process, config, frac), tol=1e-3)
        moisture_at = functools.partial(moisture, walls=process.wall_state())
        lo, hi = math.log(KAPPA_RANGE[0]), math.log(KAPPA_RANGE[1])
        m_lo, m_hi = moisture_at(lo), moisture_at(hi)
        if m_lo < 0 or m_hi > 0:
            raise SolverError(f"independent plant {structure.plant_seed}: kinetics cannot "
                              f"reach the target moisture {target:.3f} (kappa range "
                              f"{m_lo + target:.3f}..{m_hi + target:.3f})")
        new = brentq(moisture_at, lo, hi, xtol=1e-9)
        done = abs(new - log_k) < 1e-6
        log_k = new
        moisture_at(log_k)
        if done:
            break
    member = structure.commissioned(math.exp(log_k))
    process = Process(member, config)
    frac, res = operating_point(process, lambda f: nominal_inputs(process, config, f), T_sp,
                                frac)
    u = nominal_inputs(process, config, frac)
    # the loop's gain at the nominal point, walls held (what a step test on the plant shows
    # within the first minutes): K of T_dryer_out per % of flap
    pos = process.flap_position(frac)
    up = process.instant(nominal_inputs(process, config, process.hot_fraction(pos + 2.0)), 1e-3)
    down = process.instant(nominal_inputs(process, config, process.hot_fraction(pos - 2.0)),
                           1e-3)
    nominal = {
        "loop_gain": (up.T_dryer_out - down.T_dryer_out) / 4.0,
        "T_air_in": process.gas_temperature(u.e_gas, u.Y_gas, u.w_co2),
        "T_dryer_out": res.T_dryer_out, "T_cyclone_out": res.T_cyclone_out,
        "moisture_out": res.moisture_out, "moisture_tube_out": res.moisture_tube_out,
        "hot_gas_share": frac, "flap": process.flap_position(frac),
        "fibre_residence_tube": res.O_TAUP_TUBE,
        "T_fibre_max_wet": float(max([T for T, X in zip(res.profile[:, 1], res.profile[:, 2],
                                                           strict=True) if X > WET] + [0.0])),
    }
    return member, nominal


@functools.lru_cache(maxsize=64)
def _commissioned(plant_seed: int, key: tuple) -> Commissioned:
    config = _CONFIGS[key]
    problems = []
    for attempt in range(MAX_ATTEMPTS):
        structure = draw_structure(plant_seed, attempt)
        try:
            member, nominal = commission(structure, config)
        except SolverError as exc:
            problems.append(str(exc))
            continue
        if not (T_AIR_IN_RANGE[0] <= nominal["T_air_in"] <= T_AIR_IN_RANGE[1]
                and FLAP_RANGE[0] <= nominal["flap"] <= FLAP_RANGE[1]
                and nominal["T_fibre_max_wet"] < T_BOIL_WET):
            problems.append(f"attempt {attempt}: T_air_in {nominal['T_air_in']:.1f} K, "
                            f"flaps {nominal['flap']:.0f} %, wet fibre up to "
                            f"{nominal['T_fibre_max_wet']:.1f} K")
            continue
        return Commissioned(member, nominal, attempt)
    raise SolverError(f"independent plant {plant_seed}: no plausible member in "
                      f"{MAX_ATTEMPTS} draws ({problems[-1]})")


_CONFIGS: dict[tuple, PlantConfig] = {}


def commissioned_member(plant_seed: int, config: PlantConfig) -> Commissioned:
    """The commissioned member of ``plant_seed`` in ``config``'s geometry (cached)."""
    key = (config.tube, config.cyclone, config.nominal, config.environment.pressure)
    _CONFIGS.setdefault(key, config)
    return _commissioned(int(plant_seed), key)
