"""One instant of the process: tube, duct and cyclone in series, quasi-steady (compiled).

Gas passes the tube in about 3 s, the duct in under 1 s and the cyclone in about 4 s; the
fibre takes about 3 s plus its hold-up. Against the plant step (10 s) and the walls'
minutes, the flow is quasi-steady: at each step it is solved through, given the inlet and
the wall and shell temperatures, and its transit times are returned so that the day loop
can delay each output by them (:mod:`.sensors`).

Segment table columns (``S_*``): length [m], inner-h enhancement (entry and solids
loading) [-], gravity along the flow [m/s2]. The first ``n_tube`` segments are the tube
(its outlet is where ``T_dryer_out`` is measured), the rest the duct to the cyclones.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from softsensor.plant.independent.cyclone import inner_vortex
from softsensor.plant.independent.fibre import fibre_enthalpy
from softsensor.plant.independent.flow import (
    D_HI,
    D_TF,
    D_TG,
    D_UG,
    D_Y,
    N_DIAG,
    OK,
    gas_humidity_energy,
    gas_state,
    march,
)
from softsensor.plant.independent.layout import (
    IE,
    IQ,
    IU,
    IX,
    MODE_CYCLONE,
    MODE_TUBE,
    P_CDG,
    P_CYC_AREA,
    P_DIAMETER,
    P_E0,
    P_G_EFF,
    P_HI_FACTOR,
    P_KAPPA,
    P_M_DG,
    P_M_GAS,
    P_MODE,
    P_RATIO,
    P_T_HOLD,
    P_T_WALL,
    P_U_REL,
    P_UA_G,
    P_X0,
    P_XFER,
    P_Y0,
)
from softsensor.plant.independent.properties import (
    dry_gas_coefficients,
    dry_gas_molar_mass,
    h_vapour,
)

S_LEN, S_HI, S_GEFF = 0, 1, 2
N_SCOL = 3
#: Columns of the per-segment profile.
PROFILE_COLUMNS = ("T_g", "T_f", "X", "u_p", "u_g")

# cyclone inputs
C_T_HOLD, C_U_REL, C_AREA, C_UA_A, C_UA_B, C_M_LEAK, C_T_AMB, C_H_AMB, C_T_SHA, C_T_SHB = \
    range(10)
N_CIN = 10

# process inputs of one instant (``U_*``, see process.Inputs)
(U_M_FIBER, U_X_IN, U_T_FIBER, U_M_STEAM, U_M_GAS, U_E_GAS, U_Y_GAS, U_W_CO2, U_T_AMB,
 U_H_AMB, U_WIND, U_CLOUD, U_XFER, U_SURFACE, U_KAPPA_MULT, U_LOSS_MULT) = range(16)
N_U = 16

# constants of the member used per instant (``K_*``)
K_KAPPA, K_U_INJECT, K_T_HOLD, K_U_REL, K_CYC_AREA, K_UA_A, K_UA_B, K_LEAK = range(8)
N_K = 8

# outputs of one instant
(O_TG_TUBE, O_TF_TUBE, O_X_TUBE, O_Y_TUBE, O_TAUP_TUBE, O_TAUG_TUBE, O_TG_DUCT, O_X_DUCT,
 O_TAUP_DUCT, O_TAUG_DUCT, O_UG_DUCT, O_X_OUT, O_TF_OUT, O_EF_OUT, O_TG_A, O_Y_A, O_Q_A,
 O_T_MIX, O_T_CYC, O_Y_CYC, O_E_CYC, O_M_CYC, O_Q_B, O_UAEFF_B, O_STEPS,
 O_STATUS) = range(26)
N_OUT = 26

# march tolerances of a day step: outputs jitter by about 1e-3 K and 1e-5 kg/kg from step to
# step, far below the sensor noise; steady states use tighter ones (``tol_scale``)
_ATOL = np.array([1e-5, 20.0, 1e-3, 1.0])  # X, e_f [J/kg], u_p [m/s], q [J/kg]
_RTOL = 2e-4


@njit(cache=True)
def solve(p_base: np.ndarray, u: np.ndarray, k: np.ndarray, T_shell: np.ndarray,
          seg: np.ndarray, n_tube: int, Td: np.ndarray, q_seg: np.ndarray, s_seg: np.ndarray,
          prof: np.ndarray, out: np.ndarray, tol_scale: float) -> None:
    """Set up the stream of inputs ``u`` (``U_*``) for the member (``p_base``, constants
    ``k``), then :func:`solve_instant`.

    Steam joins the gas at the injection point at the fibre's temperature; the fibre enters
    at ``u_inject``.
    """
    p = p_base.copy()
    m_gas = u[U_M_GAS]
    p[P_CDG:P_CDG + 5] = dry_gas_coefficients(u[U_W_CO2])
    p[P_M_DG] = dry_gas_molar_mass(u[U_W_CO2])
    ratio = u[U_M_FIBER] / m_gas
    p[P_RATIO] = ratio
    p[P_M_GAS] = m_gas
    p[P_XFER] = u[U_XFER]
    p[P_KAPPA] = k[K_KAPPA] * u[U_KAPPA_MULT]
    e_f0 = fibre_enthalpy(u[U_T_FIBER], u[U_X_IN], p)
    p[P_X0] = u[U_X_IN]
    p[P_Y0] = u[U_Y_GAS] + u[U_M_STEAM] / m_gas
    p[P_E0] = u[U_E_GAS] + u[U_M_STEAM] / m_gas * h_vapour(u[U_T_FIBER]) + ratio * e_f0
    y = np.empty(4)
    y[IX] = u[U_X_IN]
    y[IE] = e_f0
    y[IU] = k[K_U_INJECT]
    y[IQ] = 0.0
    cyc = np.empty(N_CIN)
    cyc[C_T_HOLD] = k[K_T_HOLD]
    cyc[C_U_REL] = k[K_U_REL]
    cyc[C_AREA] = k[K_CYC_AREA] * u[U_SURFACE]
    cyc[C_UA_A] = k[K_UA_A]
    cyc[C_UA_B] = k[K_UA_B]
    cyc[C_M_LEAK] = k[K_LEAK] * m_gas
    cyc[C_T_AMB] = u[U_T_AMB]
    cyc[C_H_AMB] = u[U_H_AMB]
    cyc[C_T_SHA] = T_shell[0]
    cyc[C_T_SHB] = T_shell[1]
    solve_instant(p, y, seg, n_tube, Td, cyc, q_seg, s_seg, prof, out, tol_scale)


@njit(cache=True)
def solve_instant(p: np.ndarray, y_in: np.ndarray, seg: np.ndarray, n_tube: int,
                  Td: np.ndarray, cyc: np.ndarray, q_seg: np.ndarray, s_seg: np.ndarray,
                  prof: np.ndarray, out: np.ndarray, tol_scale: float) -> None:
    """Solve tube, duct and cyclone for one instant; fills ``q_seg`` (gas heat to each wall
    segment [W]), ``s_seg`` (gas-side conductance [W/K]), ``prof`` (state at each segment's
    end: ``T_g, T_f, X, u_p, u_g``) and ``out`` (``O_*``).

    ``p`` holds the stream set up for the tube inlet (totals ``x0, y0, e0`` of the inlet
    mixture, ``mode`` tube); it is modified in place (segment and cyclone entries).
    ``tol_scale`` multiplies the march tolerances (1 for the day, smaller for steady states).

    Kept as one compiled pass (about 93 lines): tube segments, duct and cyclone are solved in
    flow order, each handing its outlet stream in ``p`` to the next, once per instant.
    """
    atol = _ATOL * tol_scale
    rtol = _RTOL * tol_scale
    y = y_in.copy()
    diag = np.empty(N_DIAG)
    times = np.zeros(2)
    m_gas = p[P_M_GAS]
    h = 1e-3
    steps = 0
    out[O_STATUS] = OK
    p[P_MODE] = MODE_TUBE
    for j in range(seg.shape[0]):
        p[P_T_WALL] = Td[j]
        p[P_HI_FACTOR] = seg[j, S_HI]
        p[P_G_EFF] = seg[j, S_GEFF]
        q0 = y[IQ]
        gas_state(y, p, diag)
        hi0 = diag[D_HI]
        inv_ug0 = 1.0 / diag[D_UG]
        st, h, n = march(y, seg[j, S_LEN], h, p, atol, rtol, times)
        steps += n
        if st != OK:
            out[O_STATUS] = st
            return
        gas_state(y, p, diag)
        # gas transit by the trapezoidal rule over the segment (the gas velocity is smooth)
        times[1] += 0.5 * seg[j, S_LEN] * (inv_ug0 + 1.0 / diag[D_UG])
        prof[j, 0] = diag[D_TG]
        prof[j, 1] = diag[D_TF]
        prof[j, 2] = y[IX]
        prof[j, 3] = y[IU]
        prof[j, 4] = diag[D_UG]
        q_seg[j] = m_gas * (y[IQ] - q0)
        # conductance h_i A: mean of the end values (the wall update needs only a slope)
        s_seg[j] = 0.5 * (hi0 + diag[D_HI]) * np.pi * p[P_DIAMETER] * seg[j, S_LEN]
        if j == n_tube - 1:
            out[O_TG_TUBE] = diag[D_TG]
            out[O_TF_TUBE] = diag[D_TF]
            out[O_X_TUBE] = y[IX]
            out[O_Y_TUBE] = diag[D_Y]
            out[O_TAUP_TUBE] = times[0]
            out[O_TAUG_TUBE] = times[1]
    out[O_TG_DUCT] = diag[D_TG]
    out[O_X_DUCT] = y[IX]
    out[O_TAUP_DUCT] = times[0] - out[O_TAUP_TUBE]
    out[O_TAUG_DUCT] = times[1] - out[O_TAUG_TUBE]
    out[O_UG_DUCT] = diag[D_UG]
    # stage A: the outer vortex; new conserved totals at its start, heat counter reset
    e_g = gas_humidity_energy(y, p)[1]
    p[P_X0] = y[IX]
    p[P_Y0] = diag[D_Y]
    p[P_E0] = e_g + p[P_RATIO] * y[IE]
    y[IQ] = 0.0
    p[P_MODE] = MODE_CYCLONE
    p[P_T_HOLD] = cyc[C_T_HOLD]
    p[P_U_REL] = cyc[C_U_REL] * diag[D_UG]
    p[P_CYC_AREA] = cyc[C_AREA]
    p[P_UA_G] = cyc[C_UA_A] / m_gas
    p[P_T_WALL] = cyc[C_T_SHA]
    st, _, n = march(y, 1.0, 0.05, p, atol, rtol, times)
    steps += n
    if st != OK:
        out[O_STATUS] = st
        return
    gas_state(y, p, diag)
    out[O_X_OUT] = y[IX]
    out[O_TF_OUT] = diag[D_TF]
    out[O_EF_OUT] = y[IE]
    out[O_TG_A] = diag[D_TG]
    out[O_Y_A] = diag[D_Y]
    out[O_Q_A] = m_gas * y[IQ]
    e_a = gas_humidity_energy(y, p)[1]
    res = np.empty(12)
    inner_vortex(p[P_CDG:P_CDG + 5], m_gas, e_a, diag[D_Y], cyc[C_M_LEAK], cyc[C_T_AMB],
                 cyc[C_H_AMB], cyc[C_UA_B], cyc[C_T_SHB], res)
    out[O_T_MIX] = res[0]
    out[O_T_CYC] = res[1]
    out[O_Y_CYC] = res[2]
    out[O_E_CYC] = res[3]
    out[O_M_CYC] = res[4]
    out[O_Q_B] = res[5]
    out[O_UAEFF_B] = res[6]
    out[O_STEPS] = steps
