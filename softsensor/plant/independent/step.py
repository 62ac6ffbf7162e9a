"""The walls and shells of the whole plant advanced in one compiled call.

After :func:`.chain.solve` has solved the flow at one instant, :func:`advance_all` moves the
tube and duct walls (:func:`.wall.advance_walls`) and the two cyclone shell nodes
(:func:`.wall.advance_shell`) on by one plant step, with the sky temperature of the moment.
One call per step keeps the day loop's Python overhead small.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from softsensor.plant.independent.chain import (
    O_Q_A,
    O_Q_B,
    O_UAEFF_B,
    U_CLOUD,
    U_LOSS_MULT,
    U_T_AMB,
    U_WIND,
)
from softsensor.plant.independent.transfer import sky_temperature
from softsensor.plant.independent.wall import advance_shell, advance_walls

# shell constants (``SH_*``)
SH_AREA_A, SH_AREA_B, SH_UA_A, SH_C_AREA, SH_DIAM, SH_EMIS, SH_WIND = range(7)
N_SH = 7
# losses returned (``L_*``) [W]
L_TUBE, L_DUCT, L_SHELL_A, L_SHELL_B = range(4)
N_L = 4


@njit(cache=True)
def advance_all(u: np.ndarray, out: np.ndarray, q_seg: np.ndarray, s_seg: np.ndarray,
                n_tube: int, Td: np.ndarray, Ts: np.ndarray, walls: np.ndarray,
                T_shell: np.ndarray, sh: np.ndarray, dt: float, losses: np.ndarray) -> None:
    """Advance walls and shells by ``dt`` [s] (``dt <= 0``: to their steady state).

    ``u`` the instant's inputs (``chain.U_*``), ``out``/``q_seg``/``s_seg`` its flow
    solution, ``sh`` the shell constants (``SH_*``); ``losses`` receives the heat lost to the
    surroundings (``L_*``) [W] at the new temperatures.
    """
    T_amb = u[U_T_AMB]
    t_sky = sky_temperature(T_amb, u[U_CLOUD])
    q_out = np.empty(Td.shape[0])
    advance_walls(Td, Ts, walls, q_seg, s_seg, T_amb, t_sky, u[U_WIND], u[U_LOSS_MULT], dt,
                  q_out)
    losses[L_TUBE] = q_out[:n_tube].sum()
    losses[L_DUCT] = q_out[n_tube:].sum()
    wind = u[U_WIND] * sh[SH_WIND]
    T_shell[0], losses[L_SHELL_A] = advance_shell(
        T_shell[0], out[O_Q_A], sh[SH_UA_A], sh[SH_AREA_A], sh[SH_C_AREA], sh[SH_DIAM],
        sh[SH_EMIS], T_amb, t_sky, wind, u[U_LOSS_MULT], dt)
    T_shell[1], losses[L_SHELL_B] = advance_shell(
        T_shell[1], out[O_Q_B], out[O_UAEFF_B], sh[SH_AREA_B], sh[SH_C_AREA], sh[SH_DIAM],
        sh[SH_EMIS], T_amb, t_sky, wind, u[U_LOSS_MULT], dt)
