"""The compiled entry points of the dryer model: what :class:`~softsensor.model.DryerModel`
calls.

Each is ``@njit(cache=True, nogil=True)``: compiled once (numba's on-disk cache, keyed by the
sources of the whole package, :mod:`softsensor.jit_cache`), and without the GIL, so the
members of a batch run in parallel Python threads (:func:`softsensor.model.dryer.for_members`).
Each loops over its batch members and allocates its own scratch (profile, Jacobians, wall
work), so a member's numbers do not depend on which thread runs it or what runs beside it.

The model they compile is in three modules, each with its notes:

* :mod:`softsensor.model.cell_physics`: a cell's rates, coefficients and balances (paper
  eqs. 1 to 3 read as the conservation laws of :doc:`/explanation/model`), its upstream
  context packed in one array;
* :mod:`softsensor.model.cell_solver`: the Newton iterations (and last-resort bisection) for
  a cell's outlet state;
* :mod:`softsensor.model.march`: the quasi-steady profile marched down tube and cyclone, the
  Crank-Nicolson wall step, one window and the steady state of one member.

Batch layouts: inputs ``u`` (B, 8) in :data:`softsensor.signals.INPUT_NAMES` order,
parameters ``theta`` (B, 7) in :data:`softsensor.plantconfig.PARAMETER_NAMES` order,
extension coefficients ``aux`` (B, N_AUX), states (B, n_d + n_c) (wall then shell
temperatures [K]), outputs ``y`` (B, 3) in :data:`softsensor.signals.OUTPUT_NAMES` order, the
plant's geometry ``geo`` packed by :mod:`softsensor.model.geometry`; ``status`` gets the codes
of :mod:`softsensor.model.march` (``OK``, ``NEWTON_FAILED``, ``BAD_INPUT``,
``STEADY_FAILED``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from softsensor.model.geometry import N_D
from softsensor.model.march import (
    BAD_INPUT,
    NEWTON_FAILED,
    OK,
    STEADY_FAILED,
    solve_profile,
    steady_one,
    step_one,
    valid_inputs,
    wall_step,
    write_outputs,
)

__all__ = ["BAD_INPUT", "NEWTON_FAILED", "OK", "STEADY_FAILED", "advance_one", "profile_one",
           "simulate_batch", "steady_batch", "step_batch"]


@njit(cache=True, nogil=True)
def steady_batch(u, theta, aux, geo, states, y, status):
    """Steady states of a batch: ``u`` (B, 8), ``theta`` (B, 7), ``aux`` (B, N_AUX)."""
    n = states.shape[1]
    prof = np.empty((6, n))
    jac = np.empty((4, n))
    work = np.empty(4 * n)
    for b in range(u.shape[0]):
        status[b] = steady_one(states[b], u[b], theta[b], aux[b], geo, prof, jac, work)
        write_outputs(prof, geo, y[b])


@njit(cache=True, nogil=True)
def step_batch(states, u, theta, aux, geo, dt, n_sub, y, status):
    """Advance a batch of states (B, n_state) in place, member ``b`` by ``dt[b]`` seconds."""
    n = states.shape[1]
    prof = np.empty((6, n))
    jac = np.empty((4, n))
    work = np.empty(4 * n)
    for b in range(u.shape[0]):
        status[b] = step_one(states[b], u[b], theta[b], aux[b], geo, dt[b], n_sub, prof, jac,
                              work)
        write_outputs(prof, geo, y[b])


@njit(cache=True, nogil=True)
def simulate_batch(states, U, TH, AUX, geo, dt, n_sub, Y, status):
    """Run K windows for a batch: ``U`` (B, K, 8), ``TH`` (B, K, 7), ``AUX`` (B, K, N_AUX).

    ``states`` (B, n_state) holds the initial states and is advanced in place; outputs go to
    ``Y`` (B, K, 3). A member whose solve fails keeps ``status != OK`` and NaN outputs from
    then on.
    """
    n = states.shape[1]
    prof = np.empty((6, n))
    jac = np.empty((4, n))
    work = np.empty(4 * n)
    for b in range(U.shape[0]):
        status[b] = OK
        for k in range(U.shape[1]):
            st = step_one(states[b], U[b, k], TH[b, k], AUX[b, k], geo, dt, n_sub, prof, jac,
                           work)
            if st != OK:
                status[b] = st
                for kk in range(k, U.shape[1]):
                    Y[b, kk, 0] = np.nan
                    Y[b, kk, 1] = np.nan
                    Y[b, kk, 2] = np.nan
                break
            write_outputs(prof, geo, Y[b, k])


@njit(cache=True, nogil=True)
def profile_one(state, u, theta, geo, prof):
    """The steady profile (6, n_d + n_c) for one state and input: X, T_f, Y, T_a, UA_w and the
    air temperature the wall sees."""
    n_d = int(geo[N_D])
    jac = np.empty((4, state.shape[0]))
    return solve_profile(u, theta, geo, state[:n_d], state[n_d:], prof[0], prof[1], prof[2],
                         prof[3], prof[4], prof[5], jac)


@njit(cache=True, nogil=True)
def advance_one(state, u, theta, aux, geo, dt, prof, work, y):
    """Closed-loop plant step: outputs now (profile at the current wall), then the wall over
    ``dt`` [s] with that profile frozen. One profile solve per call, for short control steps
    (tens of seconds) where freezing the air profile over the step is accurate. Newton starts
    from the profile left in ``prof`` by the previous call (fill it with -1 before the first)."""
    n_d = int(geo[N_D])
    if not valid_inputs(u, theta):
        return BAD_INPUT
    Tw = state[:n_d]
    Tsh = state[n_d:]
    jac = np.full((4, state.shape[0]), np.nan)  # no Jacobians kept between calls
    st = solve_profile(u, theta, geo, Tw, Tsh, prof[0], prof[1], prof[2], prof[3], prof[4],
                       prof[5], jac, True)
    if st != OK:
        return st
    write_outputs(prof, geo, y)
    wall_step(Tw, Tsh, prof[5], prof[4], u, theta, aux, geo, dt, work)
    return OK
