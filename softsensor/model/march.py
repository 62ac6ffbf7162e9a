"""The march down the tube and the wall step: one window of one batch member.

Formulation
-----------
The paper's section 2, read as the conservation laws of :doc:`/explanation/model`.
The tube is ``n_d`` finite volumes, upwind in the flow direction, followed by ``n_c`` lumped
cyclone cells in series. Each cell has five states: fibre moisture ``X`` and temperature
``T_f``, air humidity ratio ``Y`` and temperature ``T_a``, wall (or cyclone shell)
temperature ``T_w``.

Fibre and air cross the tube in about 3 s and the cyclone in a few seconds, while the 6 mm
steel wall responds over ~10 minutes and inputs change every 600 s window. So the fast states
sit at their steady profile for the current inputs and wall temperatures, and only the wall
temperatures are integrated in time. The steady profile of an upwind finite-volume scheme is
an implicit (backward-Euler) march along the tube: cell ``i`` depends only on cell ``i-1`` and
its own wall temperature. Per cell, the water balance of fibre plus air gives ``Y`` from ``X``
exactly and the energy balance of fibre plus air gives ``T_a`` from ``(X, T_f)`` exactly, which
leaves a 2 x 2 Newton problem in ``(X, T_f)``: the fibre water and fibre energy balances. This
is the same set of algebraic equations the full method of lines (:mod:`softsensor.model.mol`)
reaches at steady state, so both agree on the outputs (checked by ``benchmarks/model.py`` and
``tests/model/test_mol.py``).

:func:`solve_profile` marches the cells (tube, then cyclone), each solved by
:func:`~softsensor.model.cell_solver.solve_cell` from its upstream context (the cell physics
are :mod:`softsensor.model.cell_physics`); :func:`wall_step` integrates the wall and shell
temperatures; :func:`step_one` and :func:`steady_one` combine them into a window and a steady
state, which the compiled entry points (:mod:`softsensor.model.kernels`) run for each member.

Wall integration: Crank-Nicolson over ``wall_substeps`` substeps of the window, the air
profile refreshed at every substep (the wall-air coupling is weak: the wall takes ~3 % of the
air's heat). Tridiagonal systems solved by the Thomas algorithm. Outside heat-loss
coefficients of the wall are evaluated at the start of each wall substep.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from softsensor.model import wood as wd
from softsensor.model.cell_physics import (
    CTX_EF,
    CTX_ETOT,
    CTX_TA,
    CTX_TF,
    CTX_TW,
    CTX_UAW,
    CTX_VS,
    CTX_X,
    CTX_Y,
    K_K,
    U_HAMB,
    U_MAIR,
    U_MFIB,
    U_MSTEAM,
    U_TAIR,
    U_TAMB,
    U_TFIB,
    U_XIN,
    ambient_film,
    inflow_coefficients,
    inlet_air,
    outside_conductance_film,
    upstream_context,
)
from softsensor.model.cell_solver import NO_JACOBIAN, solve_cell
from softsensor.model.geometry import C_SH_CELL, C_W_CELL, G_COND, N_C, N_D, X_FSP

# Solver status codes
OK, NEWTON_FAILED, BAD_INPUT, STEADY_FAILED = 0, 1, 2, 3


@register_jitable
def _cell_start(i, n_d, warm, Xo, Tfo, jac, ctx, J):
    """Where cell ``i``'s Newton starts, ``(Xg, Tfg, guess, fast, J)`` (see
    :func:`solve_profile`): with ``warm``, the previous solve's answer and the Jacobian it
    left in ``jac``; else the change across the upstream cell repeated and the upstream
    cell's Jacobian ``J``."""
    Xp = ctx[CTX_X]
    Tfp = ctx[CTX_TF]
    guess = warm and Xo[i] >= 0.0 and Tfo[i] > 200.0
    Xg = Xo[i] if guess else Xp
    Tfg = Tfo[i] if guess else Tfp
    if not guess and i >= 2 and i != n_d and Xp + (Xp - Xo[i - 2]) >= 0.0:
        Xg = Xp + (Xp - Xo[i - 2])  # Xo[i - 2], Tfo[i - 2]: this solve's
        Tfg = Tfp + (Tfp - Tfo[i - 2])
    fast = True
    if guess:
        J = (jac[0, i], jac[1, i], jac[2, i], jac[3, i])
        fast = np.isfinite(J[0])
    return Xg, Tfg, guess, fast, J


@register_jitable
def _pass_on(ctx, m_f, X, Tf, Y, Ta, hf, Tam):
    """A solved cell's outlet ``(X, T_f, Y, T_a)`` becomes the next cell's inflow in ``ctx``;
    the energy flow loses the heat the cell gave its wall, ``UA_w (T_a,w - T_w)``."""
    ctx[CTX_ETOT] -= ctx[CTX_UAW] * (Tam - ctx[CTX_TW])
    ctx[CTX_X] = X
    ctx[CTX_TF] = Tf
    ctx[CTX_Y] = Y
    ctx[CTX_TA] = Ta
    ctx[CTX_EF] = m_f * hf


@register_jitable
def solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, warm=False):
    """Steady fibre/air profile through tube and cyclone for given wall temperatures.

    Fills ``Xo, Tfo, Yo, Tao`` [kg/kg, K] and ``UAo`` (air-to-wall conductance, W/K) for all
    ``n_d + n_c`` cells, and ``Tmo``, the air temperature the wall sees (the theta-weighted
    state in tube cells); returns a status code (``OK`` or ``NEWTON_FAILED``). Each cell is
    solved by :func:`~softsensor.model.cell_solver.solve_cell` from its upstream context
    (``ctx``, :mod:`~softsensor.model.cell_physics`), which the march carries down the cells.

    Starts (:func:`_cell_start`): with ``warm``, each cell's Newton starts from the profile
    already in ``Xo, Tfo`` (the previous solve, e.g. the last wall substep) and from the
    Jacobian it left in ``jac`` (4, n_d + n_c). A cell the reference sequence solved left none
    (NaN) and starts with the plain iteration again, from its previous answer, as the
    reference does. Without a previous answer, the fast Newton starts from the upstream cell's
    Jacobian (tube and cyclone cells apart) and from the change across the upstream cell
    repeated (the profile is smooth), the reference sequence from the upstream state.
    """
    n_d = int(geo[N_D])
    n_c = int(geo[N_C])
    m_a = u[U_MAIR]
    m_f = u[U_MFIB]
    Y0, h0 = inlet_air(u, geo)
    Efp = m_f * wd.enthalpy(u[U_XIN], u[U_TFIB], geo[X_FSP])
    # what enters the first cell; wall, conductance and slip are set per cell below
    ctx = upstream_context(u[U_XIN], u[U_TFIB], Y0, u[U_TAIR], Efp, m_a * h0 + Efp, 0.0, 0.0,
                           0.0, m_a, m_f)
    J = NO_JACOBIAN
    for i in range(n_d + n_c):
        kind = 0 if i < n_d else 1
        ctx[CTX_TW] = Tw[i] if kind == 0 else Tsh[i - n_d]
        v_s, UAw = inflow_coefficients(kind, ctx[CTX_TA], ctx[CTX_Y], ctx[CTX_X], m_a, theta,
                                       geo)
        ctx[CTX_VS] = v_s
        ctx[CTX_UAW] = UAw
        if i == n_d:  # the cyclone's balances are not the tube's
            J = NO_JACOBIAN
        Xg, Tfg, guess, fast, J = _cell_start(i, n_d, warm, Xo, Tfo, jac, ctx, J)
        converged, X, Tf, out, J = solve_cell(kind, Xg, Tfg, guess, fast, ctx, theta, geo, J)
        if not converged:
            return NEWTON_FAILED
        Y, Ta, hf, Tam = out
        jac[0, i], jac[1, i], jac[2, i], jac[3, i] = J
        Xo[i] = X
        Tfo[i] = Tf
        Yo[i] = Y
        Tao[i] = Ta
        UAo[i] = UAw
        Tmo[i] = Tam
        _pass_on(ctx, m_f, X, Tf, Y, Ta, hf, Tam)
    return OK


@register_jitable
def wall_step(Tw, Tsh, Tao, UAo, u, theta, aux, geo, dt, work):
    """Advance wall and shell temperatures by ``dt`` [s] with the air profile frozen.

    Crank-Nicolson for ``C dT/dt = UA_w (T_a - T) - UA_out (T - T_amb) + G lap(T)``, with
    ``Tao`` the air temperature the wall sees (the theta-weighted state in tube cells);
    ``dt = inf`` solves the steady wall instead. ``work`` is scratch of length >= 4 n_d.
    """
    n_d = int(geo[N_D])
    n_c = int(geo[N_C])
    T_amb = u[U_TAMB]
    C = geo[C_W_CELL]
    G = theta[K_K] * geo[G_COND]
    steady = not np.isfinite(dt)
    lo = work[0:n_d]
    di = work[n_d:2 * n_d]
    up = work[2 * n_d:3 * n_d]
    rhs = work[3 * n_d:4 * n_d]
    k_amb, nu_amb, Pr_amb = ambient_film(u, geo)
    for i in range(n_d):
        Uo = outside_conductance_film(Tw[i], u, theta, aux, geo, 0, k_amb, nu_amb, Pr_amb)
        nl = 1.0 if i > 0 else 0.0
        nr = 1.0 if i < n_d - 1 else 0.0
        kd = UAo[i] + Uo + G * (nl + nr)  # diagonal of K
        b = UAo[i] * Tao[i] + Uo * T_amb
        # K T = diag*T_i - G T_{i-1} - G T_{i+1}
        KT = kd * Tw[i]
        if i > 0:
            KT -= G * Tw[i - 1]
        if i < n_d - 1:
            KT -= G * Tw[i + 1]
        if steady:
            di[i] = kd
            lo[i] = -G * nl
            up[i] = -G * nr
            rhs[i] = b
        else:
            di[i] = C / dt + 0.5 * kd
            lo[i] = -0.5 * G * nl
            up[i] = -0.5 * G * nr
            rhs[i] = C / dt * Tw[i] - 0.5 * KT + b
    # Thomas algorithm
    for i in range(1, n_d):
        m = lo[i] / di[i - 1]
        di[i] -= m * up[i - 1]
        rhs[i] -= m * rhs[i - 1]
    Tw[n_d - 1] = rhs[n_d - 1] / di[n_d - 1]
    for i in range(n_d - 2, -1, -1):
        Tw[i] = (rhs[i] - up[i] * Tw[i + 1]) / di[i]
    Cs = geo[C_SH_CELL]
    for j in range(n_c):
        Uo = outside_conductance_film(Tsh[j], u, theta, aux, geo, 1, k_amb, nu_amb, Pr_amb)
        UA = UAo[n_d + j]
        Ta = Tao[n_d + j]
        if steady:
            Tsh[j] = (UA * Ta + Uo * T_amb) / (UA + Uo)
        else:
            kd = UA + Uo
            Tsh[j] = ((Cs / dt - 0.5 * kd) * Tsh[j] + UA * Ta + Uo * T_amb) / (Cs / dt + 0.5 * kd)


@register_jitable
def valid_inputs(u, theta):
    """Whether inputs ``u`` and parameters ``theta`` are physical: all finite, parameters and
    flows positive, moisture and humidity not negative, temperatures above 250 K (150 K
    ambient). A member that is not gets ``BAD_INPUT``."""
    for v in u:
        if not np.isfinite(v):
            return False
    for v in theta:
        if not (np.isfinite(v) and v > 0.0):
            return False
    return (u[U_MAIR] > 0.0 and u[U_MFIB] > 0.0 and u[U_XIN] >= 0.0 and u[U_MSTEAM] >= 0.0
            and u[U_HAMB] >= 0.0 and u[U_TAIR] > 250.0 and u[U_TAMB] > 150.0
            and u[U_TFIB] > 250.0)


@register_jitable
def step_one(state, u, theta, aux, geo, dt, n_sub, prof, jac, work):
    """One window for one batch member: substeps of profile + wall; final profile in ``prof``
    (``jac``: scratch for the cells' Jacobians, see :func:`solve_profile`)."""
    n_d = int(geo[N_D])
    Tw = state[:n_d]
    Tsh = state[n_d:]
    Xo, Tfo, Yo, Tao, UAo, Tmo = prof[0], prof[1], prof[2], prof[3], prof[4], prof[5]
    if not valid_inputs(u, theta):
        return BAD_INPUT
    h = dt / n_sub
    # the first solve starts cold (upstream states, upstream Jacobians) so that a window's
    # result depends only on (state, u); later substeps start from the previous substep's
    # profile and Jacobians
    for k in range(n_sub):
        st = solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, k > 0)
        if st != OK:
            return st
        wall_step(Tw, Tsh, Tmo, UAo, u, theta, aux, geo, h, work)
    return solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, True)


@register_jitable
def steady_one(state, u, theta, aux, geo, prof, jac, work):
    """Steady state of one batch member: profile and steady wall iterated to a fixed point."""
    n_d = int(geo[N_D])
    n_c = int(geo[N_C])
    if not valid_inputs(u, theta):
        return BAD_INPUT
    Tw = state[:n_d]
    Tsh = state[n_d:]
    # first guess: wall between the air leaving the tube and ambient
    guess = 0.75 * 345.0 + 0.25 * u[U_TAMB]
    for i in range(n_d):
        Tw[i] = guess
    for j in range(n_c):
        Tsh[j] = guess
    Xo, Tfo, Yo, Tao, UAo, Tmo = prof[0], prof[1], prof[2], prof[3], prof[4], prof[5]
    old = np.empty(n_d + n_c)
    for it in range(100):
        for i in range(n_d + n_c):
            old[i] = state[i]
        st = solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, it > 0)
        if st != OK:
            return st
        wall_step(Tw, Tsh, Tmo, UAo, u, theta, aux, geo, np.inf, work)
        change = 0.0
        for i in range(n_d + n_c):
            change = max(change, abs(state[i] - old[i]))
        if change < 1e-9:
            return solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, True)
    return STEADY_FAILED


@register_jitable
def write_outputs(prof, geo, y):
    """The model's outputs ``y`` (3,) from a profile ``prof`` (6, n_d + n_c), in
    ``OUTPUT_NAMES`` order."""
    n_d = int(geo[N_D])
    last = prof.shape[1] - 1
    y[0] = prof[3, n_d - 1]  # T_dryer_out: air leaving the tube
    y[1] = prof[3, last]  # T_cyclone_out
    y[2] = prof[0, last]  # moisture_out: fibre leaving the cyclone
