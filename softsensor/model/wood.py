"""Wood-fibre properties: heat capacity, enthalpy, sorption, drying-rate reduction.

Moisture ``X`` is dry basis [kg water / kg dry fibre] (the paper's ``H_f``). Enthalpies are
per kg of dry fibre, referenced to 0 °C like :mod:`softsensor.model.humid_air`, so that the
energy balance of a cell closes exactly when written as enthalpy flows.

Choices where the paper is silent
---------------------------------
* Heat capacity: Wood Handbook (FPL-GTR-190, 2010) ch. 4 eqs. 4-18 and 4-19, after
  Dietenberger's compilation: ``c0 = 103.1 + 3.867 T`` [J/(kg K)] for dry wood, liquid water
  added per kg, plus the wood-water bond adjustment ``A_c = M (b1 + b2 T + b3 M)`` with ``M``
  in percent. The handbook's eq. 4-18 holds below the fibre saturation point; above it the
  wood at saturation (its bound water with the bond adjustment) carries the free water as
  plain liquid, so the adjustment, per kg of moist wood at saturation, is multiplied by
  ``1 + min(X, X_fsp)`` and not by ``1 + X`` (which made wet fibre 5 to 6 % too heavy a heat
  sink).
* Bound water: differential heat of sorption ``q = 0.4 h_fg0 (1 - X / X_fsp)^2`` below the
  fibre saturation point (Stanish, Schajer & Kayihan 1986). It enters the enthalpy as
  ``-Q_s(X)``, the integral of ``q``, so removing bound water costs ``h_fg + q`` without a
  separate source term.
* Equilibrium moisture: Hailwood-Horrobin fit of the Wood Handbook eq. 4-5 (SI form). The fit
  turns negative above about 129 °C, so the temperature is clamped to 110 °C inside it; hot
  inlet air has a tiny relative humidity there and the clamp changes the EMC by < 0.002.
* The paper's double-sigmoid reduction ``alpha(H_f)`` (after Pang 2001) is written as the
  product of two smooth factors: a logistic step from free water (1) to ``bound_fraction``
  around the critical moisture (spruce MDF fibre: constant rate down to ~1.25 kg/kg, Fritzell
  et al. 2009), and a tanh ramp that passes through 0 at the equilibrium moisture ``X_eq`` of
  the surrounding air. The ramp is signed: fibre drier than equilibrium re-adsorbs vapour
  (``alpha < 0``), as over-dried fibre does in humid air.

Drying-rate laws (``fiber.drying_law``)
---------------------------------------
The shape of the falling-rate period is where published drying physics differs, and no rate
multiplier can turn one shape into another. Three laws are compiled in, chosen per plant by
the law index packed in ``geo`` (:mod:`softsensor.model.geometry`) and dispatched inside
:func:`softsensor.model.cell_physics.drying_law` (the names:
:data:`softsensor.plantconfig.DRYING_LAWS`):

* ``double_sigmoid`` (:data:`LAW_DOUBLE_SIGMOID`, the default): the paper's ``alpha(X)``,
  :func:`drying_reduction`;
* ``cdc`` (:data:`LAW_CDC`): Keey's characteristic drying curve, :func:`cdc_reduction`;
* ``rea`` (:data:`LAW_REA`): Chen's reaction engineering approach, which lowers the vapour
  at the fibre surface instead of scaling the rate, :func:`rea_surface_factor`.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from softsensor.model.humid_air import C_W, T0
from softsensor.plantconfig import DRYING_LAWS

#: Drying-rate law indices (``geo[DRY_LAW]``): positions in the one list of law names.
LAW_DOUBLE_SIGMOID, LAW_CDC, LAW_REA = (
    DRYING_LAWS.index(n) for n in ("double_sigmoid", "cdc", "rea"))

# Wood Handbook (2010) eq. 4-19 coefficients, kJ/(kg K) with M in percent, converted to J.
_B1, _B2, _B3 = -0.06191e3, 2.36e-4 * 1e3, -1.33e-4 * 1e3


@register_jitable
def _bound(X, X_fsp):
    """Bound water ``min(max(X, 0), X_fsp)`` [kg/kg]."""
    return np.minimum(np.maximum(X, 0.0), X_fsp)


@register_jitable
def heat_capacity(X, T, X_fsp):
    """Moist-fibre heat capacity ``c_f`` [J/(kg dry fibre K)].

    Wood Handbook ch. 4 eqs. 4-18/4-19 (Dietenberger): ``c0 + X c_w + (1 + X_b) A_c(X_b)``
    with ``X_b = min(X, X_fsp)`` the bound water (module notes).

    Parameters
    ----------
    X : array_like
        Moisture, dry basis [kg/kg].
    T : array_like
        Temperature [K].
    X_fsp : float
        Fibre saturation point [kg/kg].
    """
    Xb = _bound(X, X_fsp)
    M = 100.0 * Xb
    A_c = M * (_B1 + _B2 * T + _B3 * M)
    return 103.1 + 3.867 * T + X * C_W + (1.0 + Xb) * A_c


@register_jitable
def sorption_heat(X, X_fsp, h_fg0=2.501e6):
    """Differential heat of sorption ``q`` [J/kg water] (Stanish et al. 1986)."""
    r = 1.0 - np.minimum(np.maximum(X, 0.0), X_fsp) / X_fsp
    return 0.4 * h_fg0 * r * r


@register_jitable
def _sorption_integral(X, X_fsp, h_fg0=2.501e6):
    """``Q_s(X) = int_0^X q dX`` [J / kg dry fibre]."""
    r = 1.0 - np.minimum(np.maximum(X, 0.0), X_fsp) / X_fsp
    return 0.4 * h_fg0 * X_fsp / 3.0 * (1.0 - r * r * r)


@register_jitable
def enthalpy(X, T, X_fsp):
    """Moist-fibre enthalpy ``h_f`` [J / kg dry fibre], reference 0 °C liquid water.

    ``h_f = int_T0^T c_f dT - Q_s(X)``: the temperature integral of :func:`heat_capacity`
    minus the bond energy of the bound water (see module notes).
    """
    Xb = _bound(X, X_fsp)
    M = 100.0 * Xb
    t = T - T0
    tt = 0.5 * (T * T - T0 * T0)
    dry = 103.1 * t + 3.867 * tt
    bond = (1.0 + Xb) * M * (_B1 * t + _B2 * tt + _B3 * M * t)
    return dry + X * C_W * t + bond - _sorption_integral(X, X_fsp)


@register_jitable
def equilibrium_moisture(T, phi):
    """Equilibrium moisture content ``X_eq`` [kg/kg] of wood in air at ``T`` [K], ``phi`` [-].

    Hailwood-Horrobin, Wood Handbook (2010) eq. 4-5, SI coefficients; ``T`` clamped to 110 °C
    and ``phi`` to [0, 0.99] (see module notes).
    """
    t = np.minimum(np.maximum(T - T0, 0.0), 110.0)
    h = np.minimum(np.maximum(phi, 0.0), 0.99)
    W = 349.0 + 1.29 * t + 0.0135 * t * t
    K = 0.805 + 0.000736 * t - 0.00000273 * t * t
    K1 = 6.27 - 0.00938 * t - 0.000303 * t * t
    K2 = 1.91 + 0.0407 * t - 0.000293 * t * t
    Kh = K * h
    M = 1800.0 / W * (Kh / (1.0 - Kh) + (K1 * Kh + 2.0 * K1 * K2 * Kh * Kh)
                      / (1.0 + K1 * Kh + K1 * K2 * Kh * Kh))
    return M / 100.0


@register_jitable
def drying_reduction(X, X_eq, X_cr, w_cr, alpha_b, w_eq):
    """Double-sigmoid reduction of the evaporation rate ``alpha(H_f)`` [-] (paper eq. 2).

    ``alpha = [alpha_b + (1 - alpha_b) s((X - X_cr) / w_cr)] * tanh((X - X_eq) / w_eq)``
    with ``s`` the logistic function: 1 for free water, ``alpha_b`` in the bound-water regime,
    0 at the equilibrium moisture and negative below it (re-adsorption).
    """
    s = 1.0 / (1.0 + np.exp(-(X - X_cr) / w_cr))
    ramp = np.tanh((X - X_eq) / w_eq)
    return (alpha_b + (1.0 - alpha_b) * s) * ramp


@register_jitable
def cdc_reduction(X, X_eq, X_cr, n):
    """Keey's characteristic drying curve: the rate relative to the constant-rate period [-].

    ``f = 1`` above the critical moisture ``X_cr``, ``f = Phi^n`` below it with the
    characteristic moisture ``Phi = (X - X_eq) / (X_cr - X_eq)`` (Keey, *Drying of Loose and
    Particulate Materials*, Hemisphere 1992, ch. 2; ``n = 1`` is the linear falling rate).
    Signed like :func:`drying_reduction`: ``-|Phi|^n`` below ``X_eq`` (re-adsorption).
    ``Phi`` is clipped to ``[-1, 1]`` so that air whose equilibrium moisture approaches
    ``X_cr`` (cold, nearly saturated) cannot give a factor beyond the constant rate's.
    """
    if X >= X_cr:
        return 1.0
    phi = (X - X_eq) / max(X_cr - X_eq, 1e-6)
    phi = min(max(phi, -1.0), 1.0)
    if phi >= 0.0:
        return phi**n
    return -((-phi) ** n)


@register_jitable
def rea_surface_factor(X, X_eq, phi_air, T_air, T_f, b, c):
    """Chen's reaction engineering approach: the fibre surface's vapour pressure relative to
    saturation at the fibre temperature, ``psi = p_v,s / p_sat(T_f)`` [-].

    The surface vapour is ``p_sat(T_f) exp(-dE_v / (R T_f))`` with the apparent activation
    energy ``dE_v = dE_v,inf exp(-b (X - X_eq)^c)`` and its equilibrium value
    ``dE_v,inf = -R T_air ln(phi_air)`` (Chen & Xie 1997, Food Res. Int. 30:429; Chen 2008,
    Drying Technol. 26:627), so ``psi = phi_air ^ (exp(-b (X - X_eq)^c) T_air / T_f)``: 1
    (a wet surface) far above ``X_eq``, ``phi_air ^ (T_air / T_f)`` at equilibrium (the
    air's own relative humidity where fibre and air share a temperature). The
    distance ``X - X_eq`` is taken as 0 below equilibrium (the law's ``(X - X_eq)^c`` is not
    real there); the driving force's sign then carries re-adsorption. ``phi_air`` is clipped
    to ``[0, 1]`` (supersaturated air condenses on a wet surface, ``psi = 1``).
    """
    d = max(X - X_eq, 0.0)
    ratio = np.exp(-b * d**c) * T_air / T_f
    return min(max(phi_air, 0.0), 1.0) ** ratio
