"""The cyclones: fibre hold-up with drying in the outer vortex, false air, shell losses.

Two cyclones in parallel are one equivalent unit (doubled areas and masses). The gas and the
fibre enter tangentially; the fibre is thrown to the wall at once and slides down as a
strand for its hold-up time ``t_hold`` (3 to 20 s, drawn per plant) while the gas spirals
down the outer vortex beside it. That contact is a co-current plug flow in the normalised
path ``s`` (stage A, :func:`softsensor.plant.independent.flow.march` in cyclone mode): the
strand keeps drying by the plant's kinetics law, with the strand's open surface a drawn
share of the tube's and the gas-strand velocity a drawn share of the inlet velocity, and
the gas loses heat to the cylinder and cone (shell node A).

Cyclones run under the fan's suction, so ambient air leaks in at the rotary valve of the
fibre discharge (0 to 3 % of the gas flow, drawn per plant; Hoffmann and Stein, *Gas
Cyclones and Swirl Tubes*, 2nd ed., ch. 13 show how strongly such in-leakage at the dust
outlet affects a cyclone). It joins the inner vortex at the bottom (stage B): adiabatic
mixing, then the rising inner vortex loses heat to the roof, vortex finder and outlet
(shell node B) as a single stream exchanging with a wall at constant temperature,
``T_out = T_sh + (T_mix - T_sh) exp(-UA_B / (m c_p))``. The heat given to shell B is the
stream's enthalpy drop, so the energy books close exactly.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from softsensor.plant.independent.properties import (
    CP_AIR,
    gas_cp,
    gas_enthalpy,
    gas_temperature,
)


def shell_areas(diameter: float, height: float, volume_total: float, count: int
                ) -> tuple[float, float]:
    """Total shell area [m2] of ``count`` cyclones and the cylinder height [m] of one.

    A cylinder on a cone down to a quarter of the diameter; the cylinder height is chosen
    so that the volumes add up to the configured total (kept within 30 to 90 % of the
    height), the roof included in the area.
    """
    r = 0.5 * diameter
    r_out = 0.25 * r
    v_one = volume_total / count

    def volume(h_cyl: float) -> float:
        h_cone = height - h_cyl
        return math.pi * r * r * h_cyl + math.pi * h_cone / 3.0 * (r * r + r * r_out
                                                                  + r_out * r_out)

    lo, hi = 0.3 * height, 0.9 * height
    h_cyl = min(max((v_one - volume(0.0)) / (volume(1.0) - volume(0.0)), lo), hi)
    h_cone = height - h_cyl
    slant = math.hypot(h_cone, r - r_out)
    one = (math.pi * diameter * h_cyl + math.pi * (r + r_out) * slant + math.pi * r * r)
    return count * one, h_cyl


@njit(cache=True)
def inner_vortex(cdg: np.ndarray, m_gas: float, e_g: float, Y: float, m_leak: float,
                 T_amb: float, H_amb: float, ua_b: float, T_shell: float,
                 out: np.ndarray) -> None:
    """Stage B: leak air mixes in, then the inner vortex loses heat to shell node B.

    ``cdg`` the gas's dry cp polynomial (of the stream before the leak), ``m_gas`` dry gas
    [kg/s], ``e_g`` [J/kg dry], ``Y`` [kg/kg], ``m_leak`` dry leak air [kg/s] at ``T_amb`` [K],
    ``H_amb`` [kg/kg]; ``ua_b`` [W/K] gas-side conductance to the shell at ``T_shell`` [K].
    ``out`` receives ``T_mix, T_out, Y_out, e_out [J/kg dry], m_out [kg/s], Q_B [W],
    UA_eff [W/K]`` and the mixed cp polynomial in ``out[7:12]``.
    """
    m_out = m_gas + m_leak
    wl = m_leak / m_out
    for i in range(5):
        out[7 + i] = (1.0 - wl) * cdg[i] + wl * CP_AIR[i]
    cmix = out[7:12]
    e_leak = gas_enthalpy(CP_AIR, T_amb, H_amb)
    e_mix = (1.0 - wl) * e_g + wl * e_leak
    y_mix = (1.0 - wl) * Y + wl * H_amb
    T_mix = gas_temperature(cmix, e_mix, y_mix)
    ntu = ua_b / (m_out * gas_cp(cmix, T_mix, y_mix))
    eff = -math.expm1(-ntu)
    T_out = T_mix - eff * (T_mix - T_shell)
    e_out = gas_enthalpy(cmix, T_out, y_mix)
    q_b = m_out * (e_mix - e_out)
    out[0] = T_mix
    out[1] = T_out
    out[2] = y_mix
    out[3] = e_out
    out[4] = m_out
    out[5] = q_b
    out[6] = m_out * gas_cp(cmix, T_mix, y_mix) * eff
