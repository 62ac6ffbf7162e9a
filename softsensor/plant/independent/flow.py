"""Gas-fibre plug flow: the right-hand side and its stiff-aware march (compiled).

The tube, the duct and the cyclone's outer vortex are plug flows of fibre and gas, marched
in one independent variable: the axial position ``z`` [m] in the tube and duct (fibre
velocity is a state, so the fibre residence time comes out of the drag law), or the
normalised path ``s`` in [0, 1] through the cyclone's outer vortex (the fibre takes its
hold-up time ``t_hold`` over it). The state is ``(X, e_f, u_p, q)`` of :mod:`.layout`; the gas
follows from the conserved totals.

At the tube inlet the fibre meets gas up to 300 K hotter and its temperature relaxes within
centimetres while the gas cools over metres: the system is stiff. It is marched with the
L-stable second-order Rosenbrock (modified Rosenbrock triple) of Shampine and Reichelt
(1997), *SIAM J. Sci. Comput.* 18:1 (the method of MATLAB's ``ode23s``), with a forward-
difference Jacobian at every step, a third-order error estimate and step-size control
``h_new = h min(4, max(0.2, 0.9 err^(-1/3)))``. Linear invariants are kept by any Rosenbrock
method, but the balances here do not rely on it: the gas state is computed from them.
Segments (wall elements, tube-to-duct) are integrated one after the other, the step size
carried over, so that the piecewise-constant wall temperature never sits inside a step.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from softsensor.plant.independent.fibre import evaporation_flux, fibre_temperature
from softsensor.plant.independent.layout import (
    IE,
    IQ,
    IU,
    IX,
    N_STATE,
    P_A_GEO,
    P_AREA,
    P_CDG,
    P_CYC_AREA,
    P_D_FIBRE,
    P_D_FLOC,
    P_DIAMETER,
    P_E0,
    P_FLOC,
    P_G_EFF,
    P_HI_FACTOR,
    P_HL_A,
    P_HL_B,
    P_HL_C,
    P_HL_D,
    P_M_DG,
    P_M_GAS,
    P_MODE,
    P_PRESSURE,
    P_RATIO,
    P_RHO_FLOC,
    P_T_HOLD,
    P_T_WALL,
    P_U_REL,
    P_UA_G,
    P_X0,
    P_XFER,
    P_Y0,
)
from softsensor.plant.independent.properties import (
    CP_VAP,
    density,
    diffusivity,
    gas_cp,
    gas_temperature,
    h_vapour,
    poly_cp,
    transport,
    vapour_pressure,
)
from softsensor.plant.independent.transfer import (
    ackermann,
    drag_coefficient,
    gnielinski,
    ranz_marshall,
)

OK = 0
TOO_MANY_STEPS = 1
STEP_TOO_SMALL = 2
NOT_FINITE = 3

#: Diagnostics of one state (:func:`gas_state`), in this order.
D_TG, D_TF, D_Y, D_UG, D_HI = 0, 1, 2, 3, 4
N_DIAG = 5

_D = 1.0 / (2.0 + math.sqrt(2.0))
_E32 = 6.0 + math.sqrt(2.0)
_MAX_STEPS = 20000


@njit(cache=True)
def _inner_h(T_g: float, Y: float, rho: float, u_g: float, mu: float, k: float,
             p: np.ndarray) -> float:
    """Gas-to-wall coefficient [W/(m2 K)]: Gnielinski times the segment's enhancement."""
    cdg = p[P_CDG:P_CDG + 5]
    re = rho * u_g * p[P_DIAMETER] / mu
    pr = mu * gas_cp(cdg, T_g, Y) / (1.0 + Y) / k
    return gnielinski(re, pr) * k / p[P_DIAMETER] * p[P_HI_FACTOR]


@njit(cache=True)
def gas_humidity_energy(y: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Gas humidity ``Y`` [kg/kg] and specific energy ``e_g`` [J/kg dry gas] of the march
    state ``y``: the water and energy the fibre has given up since the totals ``P_X0``,
    ``P_Y0``, ``P_E0`` were set, less the heat lost to the wall (module doc). The one place
    these balances are written."""
    Y = p[P_Y0] - p[P_RATIO] * (y[IX] - p[P_X0])
    e_g = p[P_E0] - p[P_RATIO] * y[IE] - y[IQ]
    return Y, e_g


@njit(cache=True)
def gas_state(y: np.ndarray, p: np.ndarray, out: np.ndarray) -> None:
    """Gas temperature, fibre temperature, humidity, gas velocity and inner wall h of ``y``."""
    X = y[IX]
    Y, e_g = gas_humidity_energy(y, p)
    cdg = p[P_CDG:P_CDG + 5]
    T_g = gas_temperature(cdg, e_g, Y)
    out[D_TG] = T_g
    out[D_TF] = fibre_temperature(y[IE], X, p)
    out[D_Y] = Y
    rho = density(T_g, Y, p[P_M_DG], p[P_PRESSURE])
    u_g = p[P_M_GAS] * (1.0 + Y) / (rho * p[P_AREA])
    out[D_UG] = u_g
    mu, k = transport(T_g, Y)
    out[D_HI] = _inner_h(T_g, Y, rho, u_g, mu, k, p)


@njit(cache=True)
def rhs(y: np.ndarray, p: np.ndarray, dy: np.ndarray) -> None:
    """Derivative of the march state with respect to ``z`` [1/m] or ``s`` [-] (module doc)."""
    X = y[IX]
    Y, e_g = gas_humidity_energy(y, p)
    cdg = p[P_CDG:P_CDG + 5]
    pres = p[P_PRESSURE]
    m_dg = p[P_M_DG]
    T_g = gas_temperature(cdg, e_g, Y)
    T_f = fibre_temperature(y[IE], X, p)
    pv = vapour_pressure(Y, m_dg, pres)
    w_inf = Y / (1.0 + Y)
    # film properties for the fibre's transfer coefficients
    T_m = 0.5 * (T_g + T_f)
    mu_m, k_m = transport(T_m, Y)
    rho_m = density(T_m, Y, m_dg, pres)
    cp_m = gas_cp(cdg, T_m, Y) / (1.0 + Y)
    d_f = p[P_D_FIBRE]
    tube = p[P_MODE] < 0.5
    if tube:
        rho_g = density(T_g, Y, m_dg, pres)
        u_g = p[P_M_GAS] * (1.0 + Y) / (rho_g * p[P_AREA])
        u_p = max(y[IU], 0.5)
        slip = u_g - u_p
        area = p[P_A_GEO] * p[P_FLOC] * p[P_XFER]
    else:
        slip = p[P_U_REL]
        # the strand's open surface; the tube's fouling does not reach the cyclone
        area = p[P_A_GEO] * p[P_FLOC] * p[P_CYC_AREA]
    re_f = rho_m * abs(slip) * d_f / mu_m
    h = ranz_marshall(re_f, mu_m * cp_m / k_m) * k_m / d_f
    rho_d = rho_m * diffusivity(T_m, pres)
    g = ranz_marshall(re_f, mu_m / rho_d) * rho_d / d_f
    n = evaporation_flux(X, T_f, T_g, pv, w_inf, g, p)
    q_conv = h * ackermann(n * poly_cp(CP_VAP, T_m) / h) * (T_g - T_f)
    dxdt = -area * n
    dedt = area * (q_conv - n * h_vapour(T_f))
    if tube:
        dy[IX] = dxdt / u_p
        dy[IE] = dedt / u_p
        mu_g, k_g = transport(T_g, Y)
        re_p = rho_g * abs(slip) * p[P_D_FLOC] / mu_g
        cd = drag_coefficient(re_p, p[P_HL_A], p[P_HL_B], p[P_HL_C], p[P_HL_D])
        acc = 0.75 * cd * rho_g * abs(slip) * slip / (p[P_RHO_FLOC] * (1.0 + max(X, 0.0))
                                                       * p[P_D_FLOC]) - p[P_G_EFF]
        dy[IU] = acc / u_p
        hi = _inner_h(T_g, Y, rho_g, u_g, mu_g, k_g, p)
        dy[IQ] = math.pi * p[P_DIAMETER] * hi * (T_g - p[P_T_WALL]) / p[P_M_GAS]
    else:
        t_hold = p[P_T_HOLD]
        dy[IX] = dxdt * t_hold
        dy[IE] = dedt * t_hold
        dy[IU] = 0.0
        dy[IQ] = p[P_UA_G] * (T_g - p[P_T_WALL])


@njit(cache=True)
def _lu_solve_inplace(a: np.ndarray, b: np.ndarray, piv: np.ndarray) -> None:
    n = b.shape[0]
    for i in range(n):
        j = piv[i]
        if j != i:
            b[i], b[j] = b[j], b[i]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= a[i, k] * b[k]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= a[i, k] * b[k]
        b[i] = s / a[i, i]


@njit(cache=True)
def _lu_factor_inplace(a: np.ndarray, piv: np.ndarray) -> bool:
    n = a.shape[0]
    for k in range(n):
        m = k
        big = abs(a[k, k])
        for i in range(k + 1, n):
            if abs(a[i, k]) > big:
                big = abs(a[i, k])
                m = i
        piv[k] = m
        if big == 0.0:
            return False
        if m != k:
            for j in range(n):
                a[k, j], a[m, j] = a[m, j], a[k, j]
        for i in range(k + 1, n):
            a[i, k] /= a[k, k]
            for j in range(k + 1, n):
                a[i, j] -= a[i, k] * a[k, j]
    return True


@njit(cache=True)
def march(y: np.ndarray, length: float, h0: float, p: np.ndarray, atol: np.ndarray,
          rtol: float, times: np.ndarray) -> tuple[int, float, int]:
    """Integrate ``y`` in place over ``length`` (m or -) from step size ``h0``.

    ``times[0]`` accumulates the fibre residence time [s] (trapezoidal rule over the
    accepted steps; tube mode only). Returns ``(status, last accepted step, steps)``.

    Kept as one compiled step loop (about 98 lines): the Runge-Kutta stages, the error
    estimate and the step-size control share the scratch arrays allocated once here.
    """
    n = N_STATE
    f0 = np.empty(n)
    f1 = np.empty(n)
    f2 = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    yt = np.empty(n)
    y1 = np.empty(n)
    fj = np.empty(n)
    J = np.empty((n, n))
    W = np.empty((n, n))
    piv = np.empty(n, dtype=np.int64)
    tube = p[P_MODE] < 0.5
    s = 0.0
    h = min(h0, length)
    h_last = h
    steps = 0
    rhs(y, p, f0)
    inv_up0 = 1.0 / max(y[IU], 0.5)
    while s < length * (1.0 - 1e-12):
        if steps >= _MAX_STEPS:
            return TOO_MANY_STEPS, h_last, steps
        if h < 1e-12 * max(length, 1.0):
            return STEP_TOO_SMALL, h_last, steps
        if s + h >= length * (1.0 - 1e-12):
            # the segment's end cuts the step; hand the uncut size to the next segment
            h_last = max(h_last, h)
            h = length - s
        # forward-difference Jacobian at y
        for j in range(n):
            dj = 1.5e-8 * max(abs(y[j]), atol[j] * 1e3)
            for i in range(n):
                yt[i] = y[i]
            yt[j] += dj
            rhs(yt, p, fj)
            for i in range(n):
                J[i, j] = (fj[i] - f0[i]) / dj
        for i in range(n):
            for j in range(n):
                W[i, j] = -h * _D * J[i, j]
            W[i, i] += 1.0
        if not _lu_factor_inplace(W, piv):
            h *= 0.25
            continue
        for i in range(n):
            k1[i] = f0[i]
        _lu_solve_inplace(W, k1, piv)
        for i in range(n):
            yt[i] = y[i] + 0.5 * h * k1[i]
        rhs(yt, p, f1)
        for i in range(n):
            k2[i] = f1[i] - k1[i]
        _lu_solve_inplace(W, k2, piv)
        for i in range(n):
            k2[i] += k1[i]
            y1[i] = y[i] + h * k2[i]
        rhs(y1, p, f2)
        for i in range(n):
            k3[i] = f2[i] - _E32 * (k2[i] - f1[i]) - 2.0 * (k1[i] - f0[i])
        _lu_solve_inplace(W, k3, piv)
        err = 0.0
        finite = True
        for i in range(n):
            e = h / 6.0 * (k1[i] - 2.0 * k2[i] + k3[i])
            sc = atol[i] + rtol * max(abs(y[i]), abs(y1[i]))
            r = abs(e) / sc
            if not math.isfinite(r) or not math.isfinite(f2[i]):
                finite = False
            elif r > err:
                err = r
        if not finite:
            h *= 0.25
            continue
        if err <= 1.0:
            s += h
            steps += 1
            h_last = max(h, h_last) if s >= length * (1.0 - 1e-12) else h
            if tube:
                inv_up1 = 1.0 / max(y1[IU], 0.5)
                times[0] += 0.5 * h * (inv_up0 + inv_up1)
                inv_up0 = inv_up1
            for i in range(n):
                y[i] = y1[i]
                f0[i] = f2[i]
        fac = 0.9 * max(err, 1e-10) ** (-1.0 / 3.0)
        h = h * min(4.0, max(0.2, fac))
    for i in range(n):
        if not math.isfinite(y[i]):
            return NOT_FINITE, h_last, steps
    return OK, h_last, steps
