"""Walls with thermal mass: the tube and duct in segments, the cyclone shell in two nodes.

Tube and duct: 22 tube segments of 2.5 m and 2 duct segments (not the 50 cells of the
model), each a two-node radial wall per unit area: an inner *deposit* node (fibre and
resin build-up, thickness and conductivity drawn per plant, thicker near the wet inlet)
and the *steel* node, joined by the deposit's conduction resistance plus half the steel's::

    C_d dT_d/dt = h_i (T_g - T_d) - (T_d - T_s) / R_d
    C_s dT_s/dt = (T_d - T_s) / R_d - h_conv (T_s - T_amb) - h_rad (T_s - T_rad)

The gas side enters as the heat the march gave the segment, ``Q`` [W], with its conductance
``S = h_i A`` [W/K], i.e. ``h_i A (T_g - T_d) = Q + S (T_d,old - T_d)`` so that the heat the
gas lost is the heat the wall received whenever the wall temperature stands still. The
outside is linearised at the old surface temperature (:func:`transfer.outside_coefficients`)
and the 2 x 2 system is advanced by backward Euler (L-stable: the thin deposit node has a
time constant of seconds); at steady state backward Euler's fixed point is the exact steady
state. The cyclone shell: node A (cylinder and cone, beside the outer vortex) and node B
(roof, vortex finder), one steel node each.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from softsensor.plant.independent.transfer import outside_coefficients

#: Columns of the per-segment wall table.
W_AREA, W_C_DEP, W_R_DEP, W_C_STEEL, W_DIAM, W_EMIS, W_WIND = 0, 1, 2, 3, 4, 5, 6
N_WCOL = 7


@njit(cache=True)
def _outside(T_s: float, T_amb: float, T_sky: float, wind: float, diam: float, emis: float,
             loss_mult: float) -> tuple[float, float]:
    hc, hr, t_rad = outside_coefficients(T_s, T_amb, T_sky, wind, diam, emis)
    hc *= loss_mult
    hr *= loss_mult
    h_o = hc + hr
    return h_o, (hc * T_amb + hr * t_rad) / h_o


@njit(cache=True)
def advance_walls(Td: np.ndarray, Ts: np.ndarray, wt: np.ndarray, Q: np.ndarray,
                  S: np.ndarray, T_amb: float, T_sky: float, wind: float, loss_mult: float,
                  dt: float, q_out: np.ndarray) -> None:
    """Advance the segment walls over ``dt`` [s]; ``dt <= 0`` solves the steady state.

    ``Q``/``S`` gas-side heat [W] and conductance [W/K] per segment from the march at the
    old ``Td``; ``wt`` the wall table (columns ``W_*``); ``q_out`` receives each segment's
    loss to the surroundings [W] at the new temperatures.
    """
    for j in range(Td.shape[0]):
        a = wt[j, W_AREA]
        s = S[j] / a
        tg = Td[j] + Q[j] / S[j]
        g_d = 1.0 / wt[j, W_R_DEP]
        wind_j = wind * wt[j, W_WIND]
        ts_new = Ts[j]
        td_new = Td[j]
        for _ in range(50 if dt <= 0.0 else 1):
            h_o, t_o = _outside(ts_new, T_amb, T_sky, wind_j, wt[j, W_DIAM], wt[j, W_EMIS],
                                loss_mult)
            if dt > 0.0:
                cd = wt[j, W_C_DEP] / dt
                cs = wt[j, W_C_STEEL] / dt
            else:
                cd = 0.0
                cs = 0.0
            # [cd + s + g_d, -g_d; -g_d, cs + g_d + h_o] [Td; Ts]
            #     = [cd Td0 + s tg; cs Ts0 + h_o t_o]
            a11 = cd + s + g_d
            a22 = cs + g_d + h_o
            b1 = cd * Td[j] + s * tg
            b2 = cs * Ts[j] + h_o * t_o
            det = a11 * a22 - g_d * g_d
            td_next = (b1 * a22 + g_d * b2) / det
            ts_next = (a11 * b2 + g_d * b1) / det
            done = abs(ts_next - ts_new) < 1e-11 * ts_new
            td_new = td_next
            ts_new = ts_next
            if done:
                break
        h_o, t_o = _outside(ts_new, T_amb, T_sky, wind_j, wt[j, W_DIAM], wt[j, W_EMIS],
                            loss_mult)
        q_out[j] = a * h_o * (ts_new - t_o)
        Td[j] = td_new
        Ts[j] = ts_new


@njit(cache=True)
def advance_shell(T_sh: float, Q: float, ua: float, area: float, c_area: float,
                  diam: float, emis: float, T_amb: float, T_sky: float, wind: float,
                  loss_mult: float, dt: float) -> tuple[float, float]:
    """One steel shell node: new temperature [K] and its loss to the surroundings [W].

    ``Q`` [W] gas-side heat at the old temperature through conductance ``ua`` [W/K];
    ``c_area`` heat capacity per area [J/(m2 K)]; ``dt <= 0`` solves the steady state.
    """
    tg = T_sh + Q / ua
    t_new = T_sh
    for _ in range(50 if dt <= 0.0 else 1):
        h_o, t_o = _outside(t_new, T_amb, T_sky, wind, diam, emis, loss_mult)
        c = c_area * area / dt if dt > 0.0 else 0.0
        t_next = (c * T_sh + ua * tg + area * h_o * t_o) / (c + ua + area * h_o)
        done = abs(t_next - t_new) < 1e-11 * t_new
        t_new = t_next
        if done:
            break
    h_o, t_o = _outside(t_new, T_amb, T_sky, wind, diam, emis, loss_mult)
    return t_new, area * h_o * (t_new - t_o)
