"""The solver of one cell: its outlet ``(X, T_f)`` from the upstream context.

Each cell's outlet state is the root of two residuals, fibre water and fibre energy
(:func:`~softsensor.model.cell_physics.cell_residual`, given the cell's upstream context
``ctx``); the march down the tube (:mod:`softsensor.model.march`) calls :func:`solve_cell` once
per cell and profile solve. Compiled into the kernels through ``register_jitable``.

The reference is a damped Newton with a forward-difference Jacobian (three residual
evaluations per iteration, about 10 per cell and profile solve). The profile is
solved ``wall_substeps + 1`` times per window (5 by default), each time close to the last, so
a faster Newton reuses each cell's Jacobian from the last solve (chord steps, Broyden-updated,
kept while they contract ten-fold per step), which brings a warm solve to about 4 evaluations
per cell; the window's first solve starts from the upstream cell's Jacobian and from the
profile's trend. It solves the same residual to the same test, and hands a cell to the
reference iteration wherever it would have to backtrack (a kink of the residual, where the
reference stops off the root and its stopping point is the answer); see :func:`newton_cell`
and :func:`solve_cell`. Outputs agree with the reference iteration's to about 1e-11
relative; where a cell's root lies within the finite-difference step of the kink, the
reference's line search can stall off the root while the chord steps reach it (seen in 5 of
8640 varied windows: 2e-8 relative in ``moisture_out``). The window's first solve still starts
cold, so a window's result depends only on (state, u).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from softsensor.model.cell_physics import CTX_MF, CTX_TA, CTX_TF, CTX_TW, CTX_X, cell_residual

_MAX_NEWTON = 60
#: A step with a reused cell Jacobian must cut the squared scaled residual to this fraction (the
#: residual ten-fold), or the Jacobian is recomputed (:func:`newton_cell`).
_REUSE_CONTRACTION = 1e-2
#: No Jacobian to start a cell's Newton from.
NO_JACOBIAN = (np.nan, np.nan, np.nan, np.nan)
# Halvings of a bracket in the last-resort cell solve (1 kg/kg or 300 K down to 1e-15)
_BISECTIONS = 60


@register_jitable
def _scaled_norm(F1, F2, m_f):
    """Squared residual norm with 0.01 kg/kg of moisture weighted like 1 K of fibre."""
    r1 = F1 / m_f * 100.0
    r2 = F2 / (m_f * 2000.0)
    return r1 * r1 + r2 * r2


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
def _fd_jacobian(kind, X, Tf, F1, F2, ctx, theta, geo):
    """Forward-difference Jacobian ``(j11, j21, j12, j22)`` of the cell residual at ``(X, Tf)``,
    where it is ``(F1, F2)``: two residual evaluations."""
    hx = 1e-7 * max(abs(X), 1e-3)
    ht = 1e-6 * Tf
    a1, a2, _, _, _, _ = cell_residual(kind, X + hx, Tf, ctx, theta, geo)
    b1, b2, _, _, _, _ = cell_residual(kind, X, Tf + ht, ctx, theta, geo)
    return (a1 - F1) / hx, (a2 - F2) / hx, (b1 - F1) / ht, (b2 - F2) / ht


@register_jitable
def newton_cell(kind, X, Tf, ctx, theta, geo, J, fast):
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
    the caller runs the plain one (:func:`solve_cell`).

    Returns ``(converged, X, T_f, (Y, T_a, h_f, T_a,w), J)``: the cell's other outputs at the
    returned ``(X, T_f)`` as :func:`~softsensor.model.cell_physics.cell_residual` gives them
    (the caller need not evaluate the cell again) and the Jacobian last used. The residual at
    an accepted trial point is the next iteration's residual (not evaluated twice).

    Kept as one compiled loop (about 95 lines): the iterate, the four Jacobian entries and the
    residual are scalar locals shared by the chord, Broyden and backtracking steps; split
    functions would pass them back and forth as tuples on the model's innermost path.
    """
    m_f = ctx[CTX_MF]
    F1, F2, Y, Ta, hf, Tam = cell_residual(kind, X, Tf, ctx, theta, geo)
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
                G1, G2, GY, GTa, Ghf, GTam = cell_residual(kind, Xn, Tn, ctx, theta, geo)
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
        j11, j21, j12, j22 = _fd_jacobian(kind, X, Tf, F1, F2, ctx, theta, geo)
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
            F1, F2, Y, Ta, hf, Tam = cell_residual(kind, Xn, Tn, ctx, theta, geo)
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
def _moisture_root(kind, Tf, ctx, theta, geo):
    """Outlet moisture ``X`` with zero fibre-water residual at fibre temperature ``Tf``, by
    bisection on ``[0, X_in + 1]`` (the residual falls with ``X``: less water leaves and more
    evaporates); returns ``(found, X)``."""
    lo = 0.0
    hi = ctx[CTX_X] + 1.0
    f_lo = cell_residual(kind, lo, Tf, ctx, theta, geo)[0]
    f_hi = cell_residual(kind, hi, Tf, ctx, theta, geo)[0]
    if not (f_lo >= 0.0 and f_hi <= 0.0):
        return False, 0.0
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        f = cell_residual(kind, mid, Tf, ctx, theta, geo)[0]
        if f >= 0.0:
            lo = mid
        else:
            hi = mid
    return True, 0.5 * (lo + hi)


@register_jitable
def bisect_cell(kind, ctx, theta, geo):
    """Nested bisection for a cell's outlet ``(X, T_f)``: the fibre temperature brackets the
    root of the fibre-energy residual, each trial temperature with its own water-balance
    moisture (:func:`_moisture_root`).

    The last resort of :func:`solve_cell`. Near the boiling point ``y_sat(T_f)`` climbs
    steeply and the evaporation with it, so the residual has a near-kink where the Newton's
    finite-difference Jacobian can fail from every start (seen with ``mult_h`` 1.4,
    ``mult_D`` 0.7: a fibre entering the third cell at 374.4 K). Both residuals are monotone
    along the bisections, so this finds the cell's state whenever the bracket holds it.
    Returns ``(converged, X, T_f)``.
    """
    Xp, Tfp = ctx[CTX_X], ctx[CTX_TF]
    lo = 250.0
    hi = max(ctx[CTX_TA], Tfp, ctx[CTX_TW]) + 1.0
    ok_lo, x_lo = _moisture_root(kind, lo, ctx, theta, geo)
    ok_hi, x_hi = _moisture_root(kind, hi, ctx, theta, geo)
    if not (ok_lo and ok_hi):
        return False, Xp, Tfp
    g_lo = cell_residual(kind, x_lo, lo, ctx, theta, geo)[1]
    g_hi = cell_residual(kind, x_hi, hi, ctx, theta, geo)[1]
    if not (g_lo >= 0.0 and g_hi <= 0.0):
        return False, Xp, Tfp
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        ok, X = _moisture_root(kind, mid, ctx, theta, geo)
        if not ok:
            return False, Xp, Tfp
        g = cell_residual(kind, X, mid, ctx, theta, geo)[1]
        if g >= 0.0:
            lo = mid
        else:
            hi = mid
    Tf = 0.5 * (lo + hi)
    ok, X = _moisture_root(kind, Tf, ctx, theta, geo)
    return ok, X, Tf


@register_jitable
def solve_cell(kind, Xg, Tfg, warm, fast, ctx, theta, geo, J):
    """Outlet ``(X, T_f)`` of one cell: ``(Xg, Tfg)`` is the previous solve's with ``warm``,
    else a start along the profile (:func:`~softsensor.model.march.solve_profile`).

    With ``fast``, first the fast Newton (:func:`newton_cell`, reusing the Jacobian ``J``)
    from the guess and, for a cold start, from the upstream state. Should it give up, the
    model's reference sequence, each a plain Newton: from the guess (with ``warm``), from the
    upstream state, from the fibre heated to the incoming air temperature, and last the nested
    bisection (:func:`bisect_cell`) with a Newton polish. Returns ``(converged, X, T_f, (Y,
    T_a, h_f, T_a,w), J)`` as :func:`newton_cell`, with ``J`` :data:`NO_JACOBIAN` when the
    reference sequence solved the cell.
    """
    Xp, Tfp = ctx[CTX_X], ctx[CTX_TF]
    if fast:
        ok, X, Tf, out, Jn = newton_cell(kind, Xg, Tfg, ctx, theta, geo, J, True)
        if ok:
            return ok, X, Tf, out, Jn
        if not warm and (Xg != Xp or Tfg != Tfp):
            ok, X, Tf, out, Jn = newton_cell(kind, Xp, Tfp, ctx, theta, geo, J, True)
            if ok:
                return ok, X, Tf, out, Jn
    if warm:
        ok, X, Tf, out, _ = newton_cell(kind, Xg, Tfg, ctx, theta, geo, NO_JACOBIAN, False)
        if ok:
            return ok, X, Tf, out, NO_JACOBIAN
    ok, X, Tf, out, _ = newton_cell(kind, Xp, Tfp, ctx, theta, geo, NO_JACOBIAN, False)
    if ok:
        return ok, X, Tf, out, NO_JACOBIAN
    # the fibre heated to the incoming air temperature
    ok, X, Tf, out, _ = newton_cell(kind, Xp, min(ctx[CTX_TA], 372.0), ctx, theta, geo,
                                    NO_JACOBIAN, False)
    if ok:
        return ok, X, Tf, out, NO_JACOBIAN
    # last resort: bracketing, then a Newton polish from there
    ok, X, Tf = bisect_cell(kind, ctx, theta, geo)
    if not ok:
        return ok, X, Tf, out, NO_JACOBIAN
    polished, Xn, Tn, out, _ = newton_cell(kind, X, Tf, ctx, theta, geo, NO_JACOBIAN, False)
    if polished:
        return True, Xn, Tn, out, NO_JACOBIAN
    _, _, Y, Ta, hf, Tam = cell_residual(kind, X, Tf, ctx, theta, geo)
    return True, X, Tf, (Y, Ta, hf, Tam), NO_JACOBIAN
