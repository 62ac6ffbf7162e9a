"""The physics of one cell: rates, coefficients and balances of a tube or cyclone cell.

Compiled into the kernels (:mod:`softsensor.model.kernels`) through
``numba.extending.register_jitable``; also plain Python functions, which the method of lines
(:mod:`softsensor.model.mol`) and the tests call. The model as a whole: the cells are marched
down the tube by :mod:`softsensor.model.march`, each solved by
:mod:`softsensor.model.cell_solver`.

Cell balances, per cell (steady state)::

  fibre water   m_f (X_in - X) = R
  air water     m_a (Y - Y_in) = R
  fibre energy  m_f (h_f,in - h_f) + Q_af - R h_v(T_f) = 0
  air energy    m_a (h_a,in - h_a) - Q_af - Q_w + R h_v(T_f) = 0

with enthalpies from :mod:`~softsensor.model.humid_air` (temperature-dependent heat
capacities) and :mod:`~softsensor.model.wood` (Wood Handbook), so water and energy close to
round-off when summed over the cells.

Rates (paper eqs. 1 to 3), with the high-flux driving force ``F = ln((1 + Y_s(T_f)) / (1 + Y))``::

  tube evaporation   R = mult_D alpha(X) K_c rho a dx F                          (eq. 2)
  tube heat          Q_af = mult_h h_af a dx (T_a - T_f)                         (eq. 2)
  cyclone evap.      R = A_c [hm_cyc (X - X_eq) + mult_C alpha(X) K_c rho F]     (eq. 3)
  cyclone heat       Q_af = hc_cyc A_c (T_a - T_f)                               (eq. 3)
  air to wall        Q_w = UA_w (T_a - T_w), Gnielinski's film in series with the wall's
                     inner conduction (tube) or the shell's inner coefficient (cyclone)
  wall to ambient    Q_out = UA_out (T_w - T_amb): mult_p h_out pi D_out dx
                     (Churchill-Bernstein plus natural convection and radiation) in series
                     with the wall's outer conduction (tube), h_out scaled by
                     1 + beta (283.15 K - T_amb) with beta the config's
                     environment.ambient_loss_slope (0) plus the diagnosis's extension
  wall conduction    mult_k k_w A_cross (T_w,i-1 - 2 T_w,i + T_w,i+1) / dx along the tube
                     (adiabatic ends), and mult_k on the conduction through it

``a`` is the fibre surface per metre of tube, ``A_c = a_s m_f tau_hold`` the fibre surface
held up in the cyclone, and the rates see the weighted state ``0.4 s_in + 0.6 s_i`` in the
tube (a theta scheme along x; cyclone cells are stirred tanks). Why each of these choices,
where the paper's equations are garbled or silent, and what each measurably does:
:doc:`/explanation/model` ("Choices where the paper is garbled or silent"); the symbols:
:doc:`/nomenclature`.

A cell's upstream context
-------------------------
:func:`cell_residual` and the cell solver need what enters the cell from upstream and what
the cell holds fixed while its outlet is solved: eleven numbers, packed in one float64 array
``ctx`` (as the plant's geometry is in ``geo``), indexed by the ``CTX_*`` constants below and
built by :func:`upstream_context`.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from softsensor.model import humid_air as ha
from softsensor.model import transfer as tr
from softsensor.model import wood as wd
from softsensor.model.geometry import (
    A_FLOW,
    A_SH_CELL,
    ALPHA_B,
    AMB_SLOPE,
    BETA_AMB,
    CDC_N,
    D_CYC,
    D_FIB,
    D_MEAN,
    D_OUT,
    D_P,
    DRY_LAW,
    DX,
    EMISS,
    H_IN_CYC,
    N_C,
    R_WALL_IN,
    R_WALL_OUT,
    REA_B,
    REA_C,
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

#: Theta-scheme weight of tube cells along x (see :func:`space_weight`).
SPACE_WEIGHT = 0.6

# Indices into a cell's upstream context ``ctx`` (module notes): the state entering the cell
# (fibre moisture X [kg/kg] and temperature T_f [K], air humidity ratio Y [kg/kg] and
# temperature T_a [K]), the fibre's enthalpy flow entering it E_f = m_f h_f [W], the energy
# flow of fibre plus air entering it E_tot [W], the cell's wall temperature T_w [K] and
# air-to-wall conductance UA_w [W/K], the fibre's slip velocity v_s [m/s], and the dry air and
# dry fibre flows m_a, m_f [kg/s].
CTX_X, CTX_TF, CTX_Y, CTX_TA, CTX_EF, CTX_ETOT, CTX_TW, CTX_UAW, CTX_VS, CTX_MA, CTX_MF = \
    range(11)
N_CTX = 11


@register_jitable
def upstream_context(X, Tf, Y, Ta, Ef, Etot, Tw, UAw, v_s, m_a, m_f):
    """A cell's upstream context ``ctx`` (N_CTX,) from its eleven numbers (module notes)."""
    ctx = np.empty(N_CTX)
    ctx[CTX_X] = X
    ctx[CTX_TF] = Tf
    ctx[CTX_Y] = Y
    ctx[CTX_TA] = Ta
    ctx[CTX_EF] = Ef
    ctx[CTX_ETOT] = Etot
    ctx[CTX_TW] = Tw
    ctx[CTX_UAW] = UAw
    ctx[CTX_VS] = v_s
    ctx[CTX_MA] = m_a
    ctx[CTX_MF] = m_f
    return ctx


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
def drying_law(X, Tf, Ta, phi, x_eq, geo):
    """The drying-rate law of the plant (``geo[DRY_LAW]``, ``fiber.drying_law``): the rate
    factor ``alpha`` [-] and the humidity ratio at the fibre surface ``Y_s`` [kg/kg] that the
    driving force ``ln((1 + Y_s) / (1 + Y))`` of eqs. 2 and 3 uses.

    The paper's double sigmoid and Keey's characteristic drying curve scale the rate (``alpha``
    from :func:`wood.drying_reduction` or :func:`wood.cdc_reduction`) with a saturated
    surface; Chen's reaction engineering approach keeps ``alpha = 1`` and lowers the surface
    vapour to ``psi p_sat(T_f)`` (:func:`wood.rea_surface_factor`, capped as
    :func:`humid_air.y_sat` caps ``p_sat``). ``X``, ``T_f``, ``T_a``, ``phi`` (the air's
    relative humidity) and ``x_eq`` are the cell's rate state.
    """
    Pa = geo[P]
    law = int(geo[DRY_LAW])
    if law == wd.LAW_DOUBLE_SIGMOID:
        return (wd.drying_reduction(X, x_eq, geo[X_CR], geo[W_CR], geo[ALPHA_B], geo[W_EQ]),
                ha.y_sat(Tf, Pa))
    if law == wd.LAW_CDC:
        return wd.cdc_reduction(X, x_eq, geo[X_CR], geo[CDC_N]), ha.y_sat(Tf, Pa)
    psi = wd.rea_surface_factor(X, x_eq, phi, Ta, Tf, geo[REA_B], geo[REA_C])
    p_s = min(psi * ha.p_sat(Tf), ha.P_SAT_CAP * Pa)
    return 1.0, ha.humidity_ratio(p_s, Pa)


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
    alpha, y_s = drying_law(X, Tf, Ta, phi, x_eq, geo)
    # high-flux (Stefan) driving force ln((1 + Y_s) / (1 + Y)) = ln((1 - w) / (1 - w_s)) in
    # vapour mass fractions w = Y / (1 + Y); over-dried fibre (alpha < 0) takes vapour up at a
    # rate set by its distance from equilibrium, whatever the sign of the humidity difference
    drive = np.log((1.0 + y_s) / (1.0 + Y))
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
def ambient_film(u, geo):
    """Film properties of the ambient air ``(k, nu, Pr)`` for the outside coefficients.

    The same for every wall and shell cell of a wall step, so
    :func:`~softsensor.model.march.wall_step` computes them once and passes them to
    :func:`outside_conductance_film` for each cell.
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
    # the config's slope plus the diagnosis extension's (0 + 0: the paper's law, bit for bit)
    amb = max(1.0 + (aux[BETA_AMB] + geo[AMB_SLOPE]) * (T_AMB_REF - T_amb), 0.0)
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
def cell_residual(kind, X, Tf, ctx, theta, geo):
    """Fibre water and fibre energy residuals of a cell given its outlet ``(X, T_f)`` and its
    upstream context ``ctx`` (module notes).

    ``Y`` and ``T_a`` follow from the water and energy balances of fibre plus air. Rates see
    the weighted state ``w s + (1 - w) s_in`` (:func:`space_weight`). Returns
    ``(F1 [kg/s], F2 [W], Y, T_a, h_f, T_a,w)`` with ``T_a,w`` the air temperature the wall
    sees.
    """
    Xp, Tfp, Yp, Tap = ctx[CTX_X], ctx[CTX_TF], ctx[CTX_Y], ctx[CTX_TA]
    Efp, Etot, Tw, UAw = ctx[CTX_EF], ctx[CTX_ETOT], ctx[CTX_TW], ctx[CTX_UAW]
    v_s, m_a, m_f = ctx[CTX_VS], ctx[CTX_MA], ctx[CTX_MF]
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
