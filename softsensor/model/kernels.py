"""Compiled kernels of the dryer model: cell balances, the quasi-steady profile, the wall step.

Formulation (see ``docs/model.md`` and the paper's section 2)
----------------------------------------------------------------
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
``tests/test_model_reference.py``).

Cell balances, per cell (steady state):
  fibre water   ``m_f (X_in - X) = R``
  air water     ``m_a (Y - Y_in) = R``
  fibre energy  ``m_f (h_f,in - h_f) + Q_af - R h_v(T_f) = 0``
  air energy    ``m_a (h_a,in - h_a) - Q_af - Q_w + R h_v(T_f) = 0``
with enthalpies from :mod:`humid_air` (temperature-dependent heat capacities) and :mod:`wood`
(Wood Handbook), so water and energy close to round-off when summed over the cells.

Rates (paper eqs. 1 to 3), with the high-flux driving force ``F = ln((1 + Y_s(T_f)) / (1 + Y))``:
  tube evaporation   ``R = mult_D alpha(X) K_c rho a dx F``                          (eq. 2)
  tube heat          ``Q_af = mult_h h_af a dx (T_a - T_f)``                         (eq. 2)
  cyclone evap.      ``R = A_c [hm_cyc (X - X_eq) + mult_C alpha(X) K_c rho F]``     (eq. 3)
  cyclone heat       ``Q_af = hc_cyc A_c (T_a - T_f)``                               (eq. 3)
  air to wall        ``Q_w = UA_w (T_a - T_w)``, Gnielinski's film in series with the wall's
                     inner conduction (tube) or the shell's inner coefficient (cyclone)
  wall to ambient    ``Q_out = UA_out (T_w - T_amb)``: ``mult_p h_out pi D_out dx``
                     (Churchill-Bernstein plus natural convection and radiation) in series
                     with the wall's outer conduction (tube)
  wall conduction    ``mult_k k_w A_cross (T_w,i-1 - 2 T_w,i + T_w,i+1) / dx`` along the tube
                     (adiabatic ends), and ``mult_k`` on the conduction through it (below)

Choices where the paper is garbled or silent:
* The paper's eq. 2 writes the driving force as ``H_f - H_a`` (a fibre moisture minus an air
  humidity) and divides by ``Qm_fiber``. We use the vapour flux through a stagnant film, the
  high-flux (Stefan) form ``n = K_c rho ln((1 - w_a) / (1 - w_s))`` in vapour mass fractions
  ``w = Y / (1 + Y)`` (Bird, Stewart & Lightfoot 2002, eq. 22.8-14), which is ``ln((1 + Y_s) /
  (1 + Y))``. Its low-flux limit is the linear ``rho_da (Y_s - Y)``, which overstates the
  evaporation of hot wet fibre: 2.2-fold at 368 K, where ``Y_s`` is 3. ``K_c rho a dx F`` is a
  mass flow [kg/s], and so is ``R``.
* ``a`` is fibre surface per metre of tube: specific surface [m2/kg] times dry fibre per metre
  ``m_f / v_f``.
* The cyclone (paper section 2.2; "one consistent reading" of eq. 3): the fibre is separated
  from the gas and held up for ``tau_hold`` seconds (``cyclone.hold_up_time``, 4 s), so its
  surface in the cyclone is ``A_c = a_s m_f tau_hold`` (specific surface times hold-up), shared
  equally by the ``n_c`` cells, not the tube's fibre concentration in the gas volume (which
  made the cyclone's evaporation ~1e-4 of the tube's). Eq. 3's lumped evaporation is driven
  towards the equilibrium moisture ``X_eq`` of the cell's air (negative: over-dried fibre
  re-adsorbs), with ``hm_cyc`` [kg/(m2 s)] over Table 1's 1e-7 to 1e-3; the paper's words
  under eq. 3 put ``mult_C`` "in place of ``mult_D``" in the eq. 2 form, which is added, with
  the fibre's own ``K_c``; ``hc_cyc`` [W/(m2 K)] heats the held-up fibre. So each cyclone
  parameter has its own effect: at the nominal point, across its Table 1 range, ``mult_C``
  moves ``T_cyclone_out`` by 5 K and ``moisture_out`` by 0.035 kg/kg, ``hm_cyc`` by 2.9 K and
  0.021 kg/kg, ``hc_cyc`` by 2.3 K and 0.005 kg/kg (tests/test_parameter_directions.py).
* ``mult_k`` ("heat conduction through the steel pipe", paper section 2.1) scales the wall's
  conductivity wherever it conducts: along the tube (the paper's eq. 2 Laplacian, which a 6 mm
  wall carries almost nothing through) and through the wall, from the wall node at mid-steel
  to the inner surface across the fibre deposit every MDF dryer tube carries
  (``tube.deposit_thickness``/``deposit_conductivity``, 1.5 mm at 0.12 W/(m K)) and to the
  outer surface. Over Table 1's range it moves the outlet temperatures by 1.3 K; read as axial
  conduction only, by less than 0.01 K.
* Over-dried fibre: the drying reduction ``alpha(X)`` is negative below ``X_eq``
  (:func:`wood.drying_reduction`), and the vapour is then taken up at a rate set by
  ``|F|``.
* Spatial accuracy: the balances above hold between a cell's inflow (cell ``i-1``) and its
  outflow state, while the rates (``R``, ``Q_af``, ``Q_w`` and ``h_v``) see the weighted state
  ``0.4 s_in + 0.6 s_i`` in the tube (a theta scheme along x). Plain upwind (rates at the
  outflow state, a series of stirred tanks, theta = 1) is first order, and with the steep
  drying in the first metres it left n_d = 25 0.7 K and 0.005 kg/kg away from n_d = 100. The
  box scheme (theta = 1/2) is second order but not damped: the stiff air-to-fibre heat
  exchange (fibre reaches air temperature within ~0.3 m) made the fibre temperature zig-zag
  by +-10 K over the first cells. Theta = 0.6 damps that to +-3 K and brings n_d = 25, 50 and
  100 within 0.08 K and 0.0004 kg/kg of each other (tests/test_grid_convergence.py). Cyclone
  cells stay stirred tanks (the paper's lumped cyclone).
* ``K_c`` and ``h_af`` are evaluated at that rate state; the slip velocity and the wall-side
  coefficient at the air entering the cell (they vary slowly). The full method of lines makes
  the same choices. The air temperature of a cell follows from its energy balance by a
  Newton iteration (the enthalpy is a cubic in ``T``, :func:`_air_temperature`).
* The inlet air humidity is not measured: the flaps mix hot gas (``hot_gas`` in the config)
  with ambient air; the mixing fraction follows from ``T_air_in`` by an enthalpy balance, and
  the injected steam ``m_steam`` (at ``T_fiber_in``) joins the air at the inlet.
* Outside heat-loss coefficients of the wall are evaluated at the start of each wall substep.

Wall integration: Crank-Nicolson over ``wall_substeps`` substeps of the window, the air
profile refreshed at every substep (the wall-air coupling is weak: the wall takes ~3 % of the
air's heat). Tridiagonal systems solved by the Thomas algorithm.

Cell solver: the reference is a damped Newton with a forward-difference Jacobian (three
residual evaluations per iteration, about 10 per cell and profile solve). The profile is
solved ``wall_substeps + 1`` times per window (5 by default), each time close to the last, so
a faster Newton reuses each cell's Jacobian from the last solve (chord steps, Broyden-updated,
kept while they contract ten-fold per step), which brings a warm solve to about 4 evaluations
per cell; the window's first solve starts from the upstream cell's Jacobian and from the
profile's trend. It solves the same residual to the same test, and hands a cell to the
reference iteration wherever it would have to backtrack (a kink of the residual, where the
reference stops off the root and its stopping point is the answer); see :func:`_newton_cell`
and :func:`_solve_cell`. Outputs agree with the reference iteration's to about 1e-11
relative; where a cell's root lies within the finite-difference step of the kink, the
reference's line search can stall off the root while the chord steps reach it (seen in 5 of
8640 varied windows: 2e-8 relative in ``moisture_out``). The window's first solve still starts
cold, so a window's result depends only on (state, u).
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba.extending import register_jitable

from softsensor.model import humid_air as ha
from softsensor.model import transfer as tr
from softsensor.model import wood as wd
from softsensor.model.geometry import (
    A_FLOW,
    A_SH_CELL,
    ALPHA_B,
    BETA_AMB,
    C_SH_CELL,
    C_W_CELL,
    D_CYC,
    D_FIB,
    D_MEAN,
    D_OUT,
    D_P,
    DX,
    EMISS,
    G_COND,
    H_IN_CYC,
    N_C,
    N_D,
    R_WALL_IN,
    R_WALL_OUT,
    RHO_FIB,
    S_SPEC,
    T_AMB_REF,
    T_HOT,
    TAU_HOLD,
    V_C_CELL,
    W_CR,
    W_EQ,
    WIND,
    X_CR,
    X_FSP,
    Y_HOT,
    D,
    P,
)
from softsensor.plantconfig import PARAMETER_NAMES
from softsensor.signals import INPUT_NAMES

# Input and parameter indices, from the one definition of each ordering (numba reads these
# module globals as compile-time constants).
U_TAIR, U_MAIR, U_MFIB, U_TFIB, U_MSTEAM, U_TAMB, U_HAMB, U_XIN = (
    INPUT_NAMES.index(n) for n in ("T_air_in", "m_air", "m_fiber", "T_fiber_in", "m_steam",
                                   "T_amb", "H_amb", "moisture_in"))
K_D, K_C, K_H, K_K, K_P, K_HM, K_HC = (
    PARAMETER_NAMES.index(n) for n in ("mult_D", "mult_C", "mult_h", "mult_k", "mult_p",
                                       "hm_cyc", "hc_cyc"))

# Solver status codes
OK, NEWTON_FAILED, BAD_INPUT, STEADY_FAILED = 0, 1, 2, 3

_MAX_NEWTON = 60
#: A step with a reused cell Jacobian must cut the squared scaled residual to this fraction (the
#: residual ten-fold), or the Jacobian is recomputed (:func:`_newton_cell`).
_REUSE_CONTRACTION = 1e-2
#: No Jacobian to start a cell's Newton from.
NO_JACOBIAN = (np.nan, np.nan, np.nan, np.nan)
# Halvings of a bracket in the last-resort cell solve (1 kg/kg or 300 K down to 1e-15)
_BISECTIONS = 60
#: Theta-scheme weight of tube cells along x (see :func:`space_weight`).
SPACE_WEIGHT = 0.6


@register_jitable
def inlet_air(u, geo):
    """Humidity ratio [kg/kg] and enthalpy [J/kg dry air] of the air entering the tube.

    Hot gas mixed with ambient air to ``T_air_in`` (enthalpy balance gives the mixing
    fraction), plus the injected steam at ``T_fiber_in``.
    """
    T_in, m_a, T_fin, m_st, T_amb, H_amb = (u[U_TAIR], u[U_MAIR], u[U_TFIB], u[U_MSTEAM],
                                            u[U_TAMB], u[U_HAMB])
    hv_in = ha.vapour_enthalpy(T_in)
    h_hot = ha.enthalpy(geo[T_HOT], geo[Y_HOT])
    h_amb = ha.enthalpy(T_amb, H_amb)
    # h(T_in, y_mix(f)) = f h_hot + (1 - f) h_amb with y_mix linear in f, solved for f
    num = ha.dry_air_enthalpy(T_in) + H_amb * hv_in - h_amb
    den = (h_hot - h_amb) - (geo[Y_HOT] - H_amb) * hv_in
    f = min(max(num / den, 0.0), 1.0)
    y_mix = H_amb + f * (geo[Y_HOT] - H_amb)
    y0 = y_mix + m_st / m_a
    h0 = ha.enthalpy(T_in, y_mix) + m_st / m_a * ha.vapour_enthalpy(T_fin)
    return y0, h0


@register_jitable
def series(a, b):
    """Conductance [W/K] of two conductances ``a`` and ``b`` in series (0 if either is)."""
    if a <= 0.0 or b <= 0.0:
        return 0.0
    return a * b / (a + b)


@register_jitable
def wall_conductance(theta, geo, side):
    """Conduction conductance [W/K] of one tube cell's wall from its node (mid-steel) to the
    inner surface (``side == 0``, through the fibre deposit) or the outer one (``side == 1``):
    ``mult_k pi D_m dx / R_side`` (module notes, ``mult_k``)."""
    r = geo[R_WALL_IN] if side == 0 else geo[R_WALL_OUT]
    return theta[K_K] * np.pi * geo[D_MEAN] * geo[DX] / r


@register_jitable
def inflow_coefficients(kind, Ta, Y, X, m_a, theta, geo):
    """Slip velocity [m/s] and air-to-wall conductance [W/K] from the air entering a cell.

    Tube cells: Gnielinski's film in series with the deposit and half the steel; cyclone cells:
    the configured inner coefficient of the shell.
    """
    Pa = geo[P]
    rho = ha.density(Ta, Y, Pa)
    mu, k = ha.viscosity_conductivity(Ta, Y)
    v_s = tr.slip_velocity(geo[D_P], geo[RHO_FIB] * (1.0 + X), rho, mu)
    if kind == 0:
        cp = ha.heat_capacity_mass(Ta, Y)
        v_a = m_a * (1.0 + Y) / (rho * geo[A_FLOW])
        Re = rho * v_a * geo[D] / mu
        h_aw = tr.gnielinski(Re, ha.prandtl_number(cp, mu, k)) * k / geo[D]
        return v_s, series(h_aw * np.pi * geo[D] * geo[DX], wall_conductance(theta, geo, 0))
    return v_s, geo[H_IN_CYC] * geo[A_SH_CELL]


@register_jitable
def cell_rates(kind, X, Tf, Y, Ta, v_s, m_a, m_f, theta, geo):
    """Evaporation ``R`` [kg/s] and air-to-fibre heat ``Q_af`` [W] of one cell.

    Tube cells (``kind == 0``): paper eqs. 1-2; cyclone cells: eq. 3 plus the eq. 2 form with
    ``mult_C`` (module notes). Also returns the hold-ups of dry fibre and dry air [kg] for the
    transient method of lines.
    """
    Pa = geo[P]
    rho = ha.density(Ta, Y, Pa)
    rho_da = rho / (1.0 + Y)
    phi = ha.relative_humidity(Ta, Y, Pa)
    x_eq = wd.equilibrium_moisture(Ta, phi)
    alpha = wd.drying_reduction(X, x_eq, geo[X_CR], geo[W_CR], geo[ALPHA_B], geo[W_EQ])
    # high-flux (Stefan) driving force ln((1 + Y_s) / (1 + Y)) = ln((1 - w) / (1 - w_s)) in
    # vapour mass fractions w = Y / (1 + Y); over-dried fibre (alpha < 0) takes vapour up at a
    # rate set by its distance from equilibrium, whatever the sign of the humidity difference
    drive = np.log((1.0 + ha.y_sat(Tf, Pa)) / (1.0 + Y))
    if alpha < 0.0:
        drive = abs(drive)
    mu, k = ha.viscosity_conductivity(Ta, Y)
    cp = ha.heat_capacity_mass(Ta, Y)
    Pr = ha.prandtl_number(cp, mu, k)
    Sc = ha.schmidt_number(mu, rho, ha.vapour_diffusivity(Ta, Pa))
    Re_f = rho * v_s * geo[D_FIB] / mu
    h_af = tr.churchill_bernstein(Re_f, Pr) * k / geo[D_FIB]
    K_c = tr.mass_transfer_coefficient(h_af, rho, cp, Sc, Pr)  # eq. 1
    if kind == 0:
        v_a = m_a * (1.0 + Y) / (rho * geo[A_FLOW])
        v_f = max(v_a - v_s, 0.2 * v_a)
        a_dx = geo[S_SPEC] * m_f / v_f * geo[DX]
        R = theta[K_D] * alpha * K_c * rho * a_dx * drive  # eq. 2
        Q = theta[K_H] * h_af * a_dx * (Ta - Tf)
        M_f = m_f * geo[DX] / v_f
        M_a = rho_da * geo[A_FLOW] * geo[DX]
    else:
        M_f = m_f * geo[TAU_HOLD] / geo[N_C]  # the cell's share of the fibre held up
        area = geo[S_SPEC] * M_f  # A_c: fibre surface held in the cell [m2]
        R = area * (theta[K_HM] * (X - x_eq)  # eq. 3, towards equilibrium
                    + theta[K_C] * alpha * K_c * rho * drive)  # eq. 2 form with mult_C
        Q = theta[K_HC] * area * (Ta - Tf)  # eq. 3
        M_a = rho_da * geo[V_C_CELL]
    return R, Q, M_f, M_a


@register_jitable
def _scaled_norm(F1, F2, m_f):
    """Squared residual norm with 0.01 kg/kg of moisture weighted like 1 K of fibre."""
    r1 = F1 / m_f * 100.0
    r2 = F2 / (m_f * 2000.0)
    return r1 * r1 + r2 * r2


@register_jitable
def space_weight(kind):
    """Weight ``w`` of a cell's own state in the state its rates see: ``w s_i + (1-w) s_in``.

    Tube cells use ``w = SPACE_WEIGHT`` (0.6, a damped, nearly second-order theta scheme along
    the tube, see the module notes); cyclone cells are stirred tanks (``w = 1``, rates at the
    outlet state).
    """
    return SPACE_WEIGHT if kind == 0 else 1.0


@register_jitable
def _air_temperature(rhs, m_a, Y, wUA, guess):
    """``T_a`` [K] with ``m_a h_a(T_a, Y) + wUA T_a = rhs``: Newton from ``guess`` (the
    enthalpy is a cubic in ``T``, nearly linear; a few steps reach round-off)."""
    T = guess
    for _ in range(8):
        dT = (m_a * ha.enthalpy(T, Y) + wUA * T - rhs) / (m_a * ha.heat_capacity(T, Y) + wUA)
        T -= dT
        if abs(dT) < 1e-11 * T:
            break
    return T


@register_jitable
def _cell_residual(kind, X, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw, UAw, v_s, m_a, m_f, theta,
                   geo):
    """Fibre water and fibre energy residuals of a cell given its outlet ``(X, T_f)``.

    ``Y`` and ``T_a`` follow from the water and energy balances of fibre plus air. Rates see
    the weighted state ``w s + (1 - w) s_in`` (:func:`space_weight`). Returns
    ``(F1 [kg/s], F2 [W], Y, T_a, h_f, T_a,w)`` with ``T_a,w`` the air temperature the wall
    sees.
    """
    w = space_weight(kind)
    Y = Yp + m_f / m_a * (Xp - X)
    hf = wd.enthalpy(X, Tf, geo[X_FSP])
    # m_a h_a(T_a, Y) + UAw (w T_a + (1 - w) T_ap - T_w) = Etot - m_f h_f
    Ta = _air_temperature(Etot - m_f * hf - UAw * ((1.0 - w) * Tap - Tw), m_a, Y, w * UAw, Tap)
    Tfm = w * Tf + (1.0 - w) * Tfp
    Tam = w * Ta + (1.0 - w) * Tap
    R, Q, _, _ = cell_rates(kind, w * X + (1.0 - w) * Xp, Tfm, w * Y + (1.0 - w) * Yp, Tam,
                            v_s, m_a, m_f, theta, geo)
    F1 = m_f * (Xp - X) - R
    F2 = (Efp - m_f * hf) + Q - R * ha.vapour_enthalpy(Tfm)
    return F1, F2, Y, Ta, hf, Tam


@register_jitable
def _fd_jacobian(kind, X, Tf, F1, F2, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f,
                 theta, geo):
    """Forward-difference Jacobian ``(j11, j21, j12, j22)`` of the cell residual at ``(X, Tf)``,
    where it is ``(F1, F2)``: two residual evaluations."""
    hx = 1e-7 * max(abs(X), 1e-3)
    ht = 1e-6 * Tf
    a1, a2, _, _, _, _ = _cell_residual(kind, X + hx, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i,
                                        UAw, v_s, m_a, m_f, theta, geo)
    b1, b2, _, _, _, _ = _cell_residual(kind, X, Tf + ht, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i,
                                        UAw, v_s, m_a, m_f, theta, geo)
    return (a1 - F1) / hx, (a2 - F2) / hx, (b1 - F1) / ht, (b2 - F2) / ht


@register_jitable
def _broyden(j11, j21, j12, j22, dX, dT, dF1, dF2):
    """Broyden's rank-one update of a 2 x 2 Jacobian by the secant of a step ``(dX, dT)`` that
    changed the residual by ``(dF1, dF2)``, the step measured with 0.01 kg/kg of moisture
    like 1 K (as :func:`_scaled_norm` does)."""
    r1 = dF1 - (j11 * dX + j12 * dT)
    r2 = dF2 - (j21 * dX + j22 * dT)
    wx = 1e4 * dX
    den = wx * dX + dT * dT
    return (j11 + r1 * wx / den, j21 + r2 * wx / den, j12 + r1 * dT / den,
            j22 + r2 * dT / den)


@register_jitable
def _newton_cell(kind, X, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f, theta,
                 geo, J, fast):
    """Damped Newton on a cell's outlet ``(X, T_f)`` from the guess ``(X, Tf)``, with a
    finite-difference 2 x 2 Jacobian and backtracking.

    ``fast=False`` is the plain iteration, a fresh Jacobian at every iterate: the model's
    reference. With ``fast``, Jacobians are reused, since a finite-difference one costs two
    residual evaluations and changes little between substeps and neighbouring cells: ``J =
    (j11, j21, j12, j22)`` (the cell's own from the previous profile solve or the upstream
    cell's from this one; :data:`NO_JACOBIAN`: none), then each fresh one, serves for chord
    steps, updated by Broyden's secant, as long as each such step, tried at full length, cuts
    the scaled residual at least ten-fold; otherwise the Jacobian is recomputed at the current
    iterate. The residual and the convergence test are the plain iteration's, so is the root.
    But where the plain iteration has to backtrack, its stopping point is the model's answer:
    at a kink of the residual (the capped ``y_sat`` near boiling) its line search stalls off
    the root, and the fast iteration, taking other steps, would stop elsewhere. So the fast
    iteration gives up (returns not converged) at the first step that needs backtracking, and
    the caller runs the plain one (:func:`_solve_cell`).

    Returns ``(converged, X, T_f, (Y, T_a, h_f, T_a,w), J)``: the cell's other outputs at the
    returned ``(X, T_f)`` as :func:`_cell_residual` gives them (the caller need not evaluate
    the cell again) and the Jacobian last used. The residual at an accepted trial point is the
    next iteration's residual (not evaluated twice).

    Kept as one compiled loop (about 95 lines): the iterate, the four Jacobian entries and the
    residual are scalar locals shared by the chord, Broyden and backtracking steps; split
    functions would pass them back and forth as tuples on the model's innermost path.
    """
    F1, F2, Y, Ta, hf, Tam = _cell_residual(kind, X, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i,
                                            UAw, v_s, m_a, m_f, theta, geo)
    j11, j21, j12, j22 = J
    det = j11 * j22 - j12 * j21
    reuse = fast and det != 0.0 and np.isfinite(det)
    for _ in range(_MAX_NEWTON):
        norm0 = _scaled_norm(F1, F2, m_f)
        if norm0 < 1e-24:
            return True, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)
        if reuse:  # chord step
            dX = -(F1 * j22 - F2 * j12) / det
            dT = -(j11 * F2 - j21 * F1) / det
            Xn = X + dX
            Tn = Tf + dT
            # only a full step that needs no damping is tried with a reused Jacobian
            if abs(dX) <= 0.1 and abs(dT) <= 15.0 and Xn >= 0.0:
                G1, G2, GY, GTa, Ghf, GTam = _cell_residual(kind, Xn, Tn, Xp, Tfp, Yp, Tap,
                                                            Efp, Etot, Tw_i, UAw, v_s, m_a,
                                                            m_f, theta, geo)
                norm1 = _scaled_norm(G1, G2, m_f)
                if norm1 < norm0:  # progress: keep the step
                    if norm0 > 1e-18:  # the secant is clear of round-off
                        j11, j21, j12, j22 = _broyden(j11, j21, j12, j22, dX, dT, G1 - F1,
                                                      G2 - F2)
                        det = j11 * j22 - j12 * j21
                    X, Tf = Xn, Tn
                    F1, F2, Y, Ta, hf, Tam = G1, G2, GY, GTa, Ghf, GTam
                    if norm1 > _REUSE_CONTRACTION * norm0:
                        reuse = False  # too slow: a fresh Jacobian at the next iteration
                    elif abs(dX) < 1e-10 * max(X, 1e-2) and abs(dT) < 1e-8:
                        # converged, and the contraction says the Jacobian was fit to judge
                        return True, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)
                    continue
        # a fresh Jacobian at this iterate (with fast, reused from the next iteration on)
        j11, j21, j12, j22 = _fd_jacobian(kind, X, Tf, F1, F2, Xp, Tfp, Yp, Tap, Efp, Etot,
                                          Tw_i, UAw, v_s, m_a, m_f, theta, geo)
        det = j11 * j22 - j12 * j21
        if det == 0.0 or not np.isfinite(det):
            return False, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)
        reuse = fast
        dX = -(F1 * j22 - F2 * j12) / det
        dT = -(j11 * F2 - j21 * F1) / det
        # damping: keep the step physical, then backtrack until the scaled residual
        # (moisture in kg/kg, energy in K of fibre) decreases
        lam = 1.0
        if abs(dX) > 0.1:
            lam = min(lam, 0.1 / abs(dX))
        if abs(dT) > 15.0:
            lam = min(lam, 15.0 / abs(dT))
        Xn = X
        Tn = Tf
        for _ls in range(30):
            Xn = X + lam * dX
            if Xn < 0.0:  # project: moisture stays non-negative
                Xn = 0.5 * X
            Tn = Tf + lam * dT
            F1, F2, Y, Ta, hf, Tam = _cell_residual(kind, Xn, Tn, Xp, Tfp, Yp, Tap, Efp, Etot,
                                                    Tw_i, UAw, v_s, m_a, m_f, theta, geo)
            if _scaled_norm(F1, F2, m_f) < norm0:
                break
            if fast:  # backtracking: the plain iteration decides this cell (see above)
                return False, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)
            lam *= 0.5
        # the last trial is the new iterate, with its residual already in (F1, F2, ...)
        stepX = abs(Xn - X)
        stepT = abs(Tn - Tf)
        X = Xn
        Tf = Tn
        if stepX < 1e-10 * max(X, 1e-2) and stepT < 1e-8:
            return True, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)
    return False, X, Tf, (Y, Ta, hf, Tam), (j11, j21, j12, j22)


@register_jitable
def _moisture_root(kind, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f, theta,
                   geo):
    """Outlet moisture ``X`` with zero fibre-water residual at fibre temperature ``Tf``, by
    bisection on ``[0, X_in + 1]`` (the residual falls with ``X``: less water leaves and more
    evaporates); returns ``(found, X)``."""
    lo = 0.0
    hi = Xp + 1.0
    f_lo = _cell_residual(kind, lo, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                          m_f, theta, geo)[0]
    f_hi = _cell_residual(kind, hi, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                          m_f, theta, geo)[0]
    if not (f_lo >= 0.0 and f_hi <= 0.0):
        return False, 0.0
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        f = _cell_residual(kind, mid, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                           m_f, theta, geo)[0]
        if f >= 0.0:
            lo = mid
        else:
            hi = mid
    return True, 0.5 * (lo + hi)


@register_jitable
def _bisect_cell(kind, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f, theta, geo):
    """Nested bisection for a cell's outlet ``(X, T_f)``: the fibre temperature brackets the
    root of the fibre-energy residual, each trial temperature with its own water-balance
    moisture (:func:`_moisture_root`).

    The last resort of :func:`solve_profile`. Near the boiling point ``y_sat(T_f)`` climbs
    steeply and the evaporation with it, so the residual has a near-kink where the Newton's
    finite-difference Jacobian can fail from every start (seen with ``mult_h`` 1.4,
    ``mult_D`` 0.7: a fibre entering the third cell at 374.4 K). Both residuals are monotone
    along the bisections, so this finds the cell's state whenever the bracket holds it.
    Returns ``(converged, X, T_f)``.
    """
    lo = 250.0
    hi = max(Tap, Tfp, Tw_i) + 1.0
    ok_lo, x_lo = _moisture_root(kind, lo, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                                 m_f, theta, geo)
    ok_hi, x_hi = _moisture_root(kind, hi, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                                 m_f, theta, geo)
    if not (ok_lo and ok_hi):
        return False, Xp, Tfp
    g_lo = _cell_residual(kind, x_lo, lo, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                          m_f, theta, geo)[1]
    g_hi = _cell_residual(kind, x_hi, hi, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                          m_f, theta, geo)[1]
    if not (g_lo >= 0.0 and g_hi <= 0.0):
        return False, Xp, Tfp
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        ok, X = _moisture_root(kind, mid, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                               m_f, theta, geo)
        if not ok:
            return False, Xp, Tfp
        g = _cell_residual(kind, X, mid, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                           m_f, theta, geo)[1]
        if g >= 0.0:
            lo = mid
        else:
            hi = mid
    Tf = 0.5 * (lo + hi)
    ok, X = _moisture_root(kind, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f,
                           theta, geo)
    return ok, X, Tf


@register_jitable
def _solve_cell(kind, Xg, Tfg, warm, fast, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a,
                m_f, theta, geo, J):
    """Outlet ``(X, T_f)`` of one cell: ``(Xg, Tfg)`` is the previous solve's with ``warm``,
    else a start along the profile (:func:`solve_profile`).

    With ``fast``, first the fast Newton (:func:`_newton_cell`, reusing the Jacobian ``J``)
    from the guess and, for a cold start, from the upstream state. Should it give up, the
    model's reference sequence, each a plain Newton: from the guess (with ``warm``), from the
    upstream state, from the fibre heated to the incoming air temperature, and last the nested
    bisection (:func:`_bisect_cell`) with a Newton polish. Returns ``(converged, X, T_f, (Y,
    T_a, h_f, T_a,w), J)`` as :func:`_newton_cell`, with ``J`` :data:`NO_JACOBIAN` when the
    reference sequence solved the cell.
    """
    if fast:
        ok, X, Tf, out, Jn = _newton_cell(kind, Xg, Tfg, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw,
                                          v_s, m_a, m_f, theta, geo, J, True)
        if ok:
            return ok, X, Tf, out, Jn
        if not warm and (Xg != Xp or Tfg != Tfp):
            ok, X, Tf, out, Jn = _newton_cell(kind, Xp, Tfp, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i,
                                              UAw, v_s, m_a, m_f, theta, geo, J, True)
            if ok:
                return ok, X, Tf, out, Jn
    if warm:
        ok, X, Tf, out, _ = _newton_cell(kind, Xg, Tfg, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw,
                                         v_s, m_a, m_f, theta, geo, NO_JACOBIAN, False)
        if ok:
            return ok, X, Tf, out, NO_JACOBIAN
    ok, X, Tf, out, _ = _newton_cell(kind, Xp, Tfp, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s,
                                     m_a, m_f, theta, geo, NO_JACOBIAN, False)
    if ok:
        return ok, X, Tf, out, NO_JACOBIAN
    # the fibre heated to the incoming air temperature
    ok, X, Tf, out, _ = _newton_cell(kind, Xp, min(Tap, 372.0), Xp, Tfp, Yp, Tap, Efp, Etot,
                                     Tw_i, UAw, v_s, m_a, m_f, theta, geo, NO_JACOBIAN, False)
    if ok:
        return ok, X, Tf, out, NO_JACOBIAN
    # last resort: bracketing, then a Newton polish from there
    ok, X, Tf = _bisect_cell(kind, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw, v_s, m_a, m_f,
                             theta, geo)
    if not ok:
        return ok, X, Tf, out, NO_JACOBIAN
    polished, Xn, Tn, out, _ = _newton_cell(kind, X, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i,
                                            UAw, v_s, m_a, m_f, theta, geo, NO_JACOBIAN, False)
    if polished:
        return True, Xn, Tn, out, NO_JACOBIAN
    _, _, Y, Ta, hf, Tam = _cell_residual(kind, X, Tf, Xp, Tfp, Yp, Tap, Efp, Etot, Tw_i, UAw,
                                          v_s, m_a, m_f, theta, geo)
    return True, X, Tf, (Y, Ta, hf, Tam), NO_JACOBIAN


@register_jitable
def solve_profile(u, theta, geo, Tw, Tsh, Xo, Tfo, Yo, Tao, UAo, Tmo, jac, warm=False):
    """Steady fibre/air profile through tube and cyclone for given wall temperatures.

    Fills ``Xo, Tfo, Yo, Tao`` [kg/kg, K] and ``UAo`` (air-to-wall conductance, W/K) for all
    ``n_d + n_c`` cells, and ``Tmo``, the air temperature the wall sees (the theta-weighted
    state in tube cells); returns a status code (``OK`` or ``NEWTON_FAILED``). Each cell is
    solved by :func:`_solve_cell`.

    Starts: with ``warm``, each cell's Newton starts from the profile already in ``Xo, Tfo``
    (the previous solve, e.g. the last wall substep) and from the Jacobian it left in ``jac``
    (4, n_d + n_c). A cell the reference sequence solved left none (NaN) and starts with the
    plain iteration again, from its previous answer, as the reference does. Without a previous
    answer, the fast Newton starts from the upstream cell's Jacobian (tube and cyclone cells
    apart) and from the change across the upstream cell repeated (the profile is smooth), the
    reference sequence from the upstream state.

    Kept as one compiled pass down the cells (about 63 lines): the upstream cell's outlet and
    Jacobian are the loop's carried scalars, and the tube-to-cyclone switch happens inside it.
    """
    n_d = int(geo[N_D])
    n_c = int(geo[N_C])
    m_a = u[U_MAIR]
    m_f = u[U_MFIB]
    Xp = u[U_XIN]
    Tfp = u[U_TFIB]
    Yp, h0 = inlet_air(u, geo)
    Tap = u[U_TAIR]
    Efp = m_f * wd.enthalpy(Xp, Tfp, geo[X_FSP])
    Etot = m_a * h0 + Efp
    J = NO_JACOBIAN
    for i in range(n_d + n_c):
        kind = 0 if i < n_d else 1
        Tw_i = Tw[i] if kind == 0 else Tsh[i - n_d]
        v_s, UAw = inflow_coefficients(kind, Tap, Yp, Xp, m_a, theta, geo)
        if i == n_d:  # the cyclone's balances are not the tube's
            J = NO_JACOBIAN
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
        converged, X, Tf, out, J = _solve_cell(kind, Xg, Tfg, guess, fast, Xp, Tfp, Yp, Tap,
                                               Efp, Etot, Tw_i, UAw, v_s, m_a, m_f, theta, geo,
                                               J)
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
        Etot -= UAw * (Tam - Tw_i)
        Xp = X
        Tfp = Tf
        Yp = Y
        Tap = Ta
        Efp = m_f * hf
    return OK


@register_jitable
def ambient_film(u, geo):
    """Film properties of the ambient air ``(k, nu, Pr)`` for the outside coefficients.

    The same for every wall and shell cell of a wall step, so :func:`wall_step` computes them
    once and passes them to :func:`outside_conductance_film` for each cell.
    """
    T_amb = u[U_TAMB]
    H_amb = u[U_HAMB]
    mu, k = ha.viscosity_conductivity(T_amb, H_amb)
    nu = mu / ha.density(T_amb, H_amb, geo[P])
    Pr = ha.prandtl_number(ha.heat_capacity_mass(T_amb, H_amb), mu, k)
    return k, nu, Pr


@register_jitable
def outside_conductance_film(T_w, u, theta, aux, geo, kind, k, nu, Pr):
    """:func:`outside_conductance` with the ambient film properties of :func:`ambient_film`
    given."""
    T_amb = u[U_TAMB]
    amb = max(1.0 + aux[BETA_AMB] * (T_AMB_REF - T_amb), 0.0)
    if kind == 0:
        h = tr.outside_coefficient(T_w, T_amb, geo[D_OUT], geo[WIND], geo[EMISS], k, nu, Pr)
        return series(theta[K_P] * amb * h * np.pi * geo[D_OUT] * geo[DX],
                      wall_conductance(theta, geo, 1))
    h = tr.outside_coefficient(T_w, T_amb, geo[D_CYC], geo[WIND], geo[EMISS], k, nu, Pr)
    return theta[K_P] * amb * h * geo[A_SH_CELL]


@register_jitable
def outside_conductance(T_w, u, theta, aux, geo, kind):
    """Wall-to-ambient conductance [W/K] of a tube cell (``mult_p h_out A`` in series with the
    outer half of the steel) or a cyclone shell cell (``mult_p h_out A``)."""
    k, nu, Pr = ambient_film(u, geo)
    return outside_conductance_film(T_w, u, theta, aux, geo, kind, k, nu, Pr)


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
def _valid_inputs(u, theta):
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
def _step_one(state, u, theta, aux, geo, dt, n_sub, prof, jac, work):
    """One window for one batch member: substeps of profile + wall; final profile in ``prof``
    (``jac``: scratch for the cells' Jacobians, see :func:`solve_profile`)."""
    n_d = int(geo[N_D])
    Tw = state[:n_d]
    Tsh = state[n_d:]
    Xo, Tfo, Yo, Tao, UAo, Tmo = prof[0], prof[1], prof[2], prof[3], prof[4], prof[5]
    if not _valid_inputs(u, theta):
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
def _steady_one(state, u, theta, aux, geo, prof, jac, work):
    """Steady state of one batch member: profile and steady wall iterated to a fixed point."""
    n_d = int(geo[N_D])
    n_c = int(geo[N_C])
    if not _valid_inputs(u, theta):
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
def _outputs(prof, geo, y):
    n_d = int(geo[N_D])
    last = prof.shape[1] - 1
    y[0] = prof[3, n_d - 1]  # T_dryer_out: air leaving the tube
    y[1] = prof[3, last]  # T_cyclone_out
    y[2] = prof[0, last]  # moisture_out: fibre leaving the cyclone


@njit(cache=True, nogil=True)
def steady_batch(u, theta, aux, geo, states, y, status):
    """Steady states of a batch: ``u`` (B, 8), ``theta`` (B, 7), ``aux`` (B, N_AUX)."""
    n = states.shape[1]
    prof = np.empty((6, n))
    jac = np.empty((4, n))
    work = np.empty(4 * n)
    for b in range(u.shape[0]):
        status[b] = _steady_one(states[b], u[b], theta[b], aux[b], geo, prof, jac, work)
        _outputs(prof, geo, y[b])


@njit(cache=True, nogil=True)
def step_batch(states, u, theta, aux, geo, dt, n_sub, y, status):
    """Advance a batch of states (B, n_state) in place, member ``b`` by ``dt[b]`` seconds."""
    n = states.shape[1]
    prof = np.empty((6, n))
    jac = np.empty((4, n))
    work = np.empty(4 * n)
    for b in range(u.shape[0]):
        status[b] = _step_one(states[b], u[b], theta[b], aux[b], geo, dt[b], n_sub, prof, jac,
                              work)
        _outputs(prof, geo, y[b])


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
            st = _step_one(states[b], U[b, k], TH[b, k], AUX[b, k], geo, dt, n_sub, prof, jac,
                           work)
            if st != OK:
                status[b] = st
                for kk in range(k, U.shape[1]):
                    Y[b, kk, 0] = np.nan
                    Y[b, kk, 1] = np.nan
                    Y[b, kk, 2] = np.nan
                break
            _outputs(prof, geo, Y[b, k])


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
    if not _valid_inputs(u, theta):
        return BAD_INPUT
    Tw = state[:n_d]
    Tsh = state[n_d:]
    jac = np.full((4, state.shape[0]), np.nan)  # no Jacobians kept between calls
    st = solve_profile(u, theta, geo, Tw, Tsh, prof[0], prof[1], prof[2], prof[3], prof[4],
                       prof[5], jac, True)
    if st != OK:
        return st
    _outputs(prof, geo, y)
    wall_step(Tw, Tsh, prof[5], prof[4], u, theta, aux, geo, dt, work)
    return OK
