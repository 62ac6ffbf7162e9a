"""The steady-state search over the outlet-temperature set point, the heat duty, the settle.

The plant's own loop holds ``T_dryer_out`` at ``T_sp`` by moving the flaps, which set
``T_air_in``. So a set point ``T_sp'`` is a steady state of the model at the ``T_air_in'``
that gives the outlet temperature the plant will then read, with every other input as it is
now (the inlet moisture as estimated). One batched call of the model's front door
(:meth:`softsensor.model.DryerModel.steady_state`) solves a grid of ``T_air_in`` values for
the calibrated parameters and for each parameter moved by ``+-STEP`` in ``ln(theta)``: the
outlet temperature and moisture along the grid, member by member.

What the advice leans on is the model's *change* of the outlet moisture from now to the new
set point, not its level: the level is the published estimate (its band holds what the lab
results and the filter know), and the change is added to it. The model's outlet temperature
is read the same way, as a change: ``T_sp' - T_dryer_out(now)`` measured is asked of the
model as a change from its own outlet temperature now, so an offset between the model and the
thermometer cancels. The change's uncertainty comes from the parameters' covariance ``C``
(the identifiability result, in ``ln(theta)``): ``var = g^T C g`` with ``g`` the change's
sensitivity to ``ln(theta)`` by central differences. The predicted outlet moisture at ``T_sp'``
is then ``m_now + dm`` with variance ``s_now^2 + g^T C g`` (the estimate's error and the
parameters' are independent: one is what the labs have not yet seen, the other what the
calibration history could not pin down).

The heat duty is the burner's: the dry air heated from ambient to ``T_air_in``,
``Q = m_air (h(T_air_in, H_amb) - h(T_amb, H_amb))`` with the model's humid-air enthalpy
[W]; per tonne of dry fibre ``Q / (m_fiber 3.6)`` [kWh/t]. Burner losses and the combustion
water are left out: the same for both set points, they cancel in the saving up to the
burner's efficiency.

No I/O here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsensor.errors import SolverError
from softsensor.model import DryerModel
from softsensor.model.humid_air import enthalpy
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES

#: Step in ln(theta) of the central differences (1 %: the identifiability analysis's own,
#: :data:`softsensor.calibration.identifiability.SENSITIVITY_STEP`).
STEP = 1e-2
#: Points of the coarse T_air_in grid over the envelope (calibrated parameters only): about
#: 4 K apart over a 90 K envelope, enough to find where the set points lie.
GRID_POINTS = 25
#: Points of the fine grid every parameter member is solved on, over the T_air_in range the
#: set points within reach need: 1 to 3 K apart, where linear interpolation of the outlet
#: moisture errs by less than 6e-4 kg/kg (a fifth of the lab's noise; the tests measure it).
LOCAL_POINTS = 17
#: Padding of the fine grid beyond the set points' range [K of T_air_in].
LOCAL_PAD = 3.0
#: Set-point resolution of the search [K]: at the 0.02 kg/kg per K the plants show, a
#: moisture step of 4e-4 kg/kg, a tenth of the lab's noise.
SP_RESOLUTION = 0.02
#: Time step of the settling simulation [s].
SETTLE_DT = 300.0

_TA = INPUT_NAMES.index("T_air_in")
_MA = INPUT_NAMES.index("m_air")
_MF = INPUT_NAMES.index("m_fiber")
_TAMB = INPUT_NAMES.index("T_amb")
_HAMB = INPUT_NAMES.index("H_amb")
_TD = OUTPUT_NAMES.index("T_dryer_out")
_MO = OUTPUT_NAMES.index("moisture_out")


def heat_duty(u: np.ndarray) -> float:
    """Steady heat duty of the burner at inputs ``u`` (8,): dry air from ambient to
    ``T_air_in``. [W]"""
    h = enthalpy(u[_TA], u[_HAMB]) - enthalpy(u[_TAMB], u[_HAMB])
    return float(u[_MA] * h)


def per_tonne(duty_w: float, m_fiber: float) -> float:
    """Heat per tonne of dry fibre [kWh/t] of a duty [W] at a dry-fibre flow [kg/s]."""
    return duty_w / 1e3 / (m_fiber * 3.6)


def members(theta: np.ndarray, step: float = STEP) -> np.ndarray:
    """The calibrated parameters and each moved by ``+-step`` in ln(theta): (15, 7), member
    ``1 + 2 i`` up and ``2 + 2 i`` down for parameter ``i``."""
    theta = np.asarray(theta, float)
    out = np.tile(theta, (2 * theta.size + 1, 1))
    for i in range(theta.size):
        out[1 + 2 * i, i] *= math.exp(step)
        out[2 + 2 * i, i] *= math.exp(-step)
    return out


@dataclass(frozen=True)
class Curves:
    """The model's steady outlet temperature and moisture along a ``T_air_in`` grid, for
    each member of :func:`members`.

    Attributes
    ----------
    T_air_in : ndarray (G,)
        The grid. [K]
    T_dryer_out, moisture_out : ndarray (M, G)
        Steady outputs per member along the grid. [K, kg/kg]
    u : ndarray (8,)
        The inputs now (``T_air_in`` as measured).
    """

    T_air_in: np.ndarray
    T_dryer_out: np.ndarray
    moisture_out: np.ndarray
    u: np.ndarray

    def at(self, T_air_in: float) -> tuple[np.ndarray, np.ndarray]:
        """Each member's outlet temperature and moisture at ``T_air_in`` (M,) each."""
        g = self.T_air_in
        return (np.array([np.interp(T_air_in, g, t) for t in self.T_dryer_out]),
                np.array([np.interp(T_air_in, g, m) for m in self.moisture_out]))


def _steady_grid(model: DryerModel, u: np.ndarray, thetas: np.ndarray, grid: np.ndarray,
                 monotone: bool = True) -> Curves:
    U = np.broadcast_to(np.asarray(u, float), (grid.size, len(INPUT_NAMES))).copy()
    U[:, _TA] = grid
    _, y = model.steady_state(U[None], thetas[:, None, :])
    T, m = y[..., _TD], y[..., _MO]
    if monotone and not np.all(np.diff(T, axis=1) > 0):
        raise SolverError("the model's outlet temperature does not rise with T_air_in over "
                          f"{grid[0]:.1f} to {grid[-1]:.1f} K")
    return Curves(grid, T, m, np.asarray(u, float))


def curves(model: DryerModel, u: np.ndarray, theta: np.ndarray, lo: float, hi: float,
           T_dryer_out_now: float, sp_lo: float, sp_hi: float) -> Curves:
    """Steady states of every parameter member of ``theta`` around the ``T_air_in`` that the
    set points ``sp_lo`` to ``sp_hi`` [K] need, within ``lo`` to ``hi`` [K] (the envelope),
    at inputs ``u`` (8,), the outlet reading ``T_dryer_out_now`` [K] now.

    Two batched calls: the calibrated parameters on :data:`GRID_POINTS` over ``lo`` to
    ``hi`` find the ``T_air_in`` range the set points need, then every member on
    :data:`LOCAL_POINTS` over that range (plus :data:`LOCAL_PAD` each side) gives the curves
    the search reads. Raises :class:`~softsensor.errors.SolverError` when a member fails or
    its outlet temperature does not rise with ``T_air_in`` (no set point could then be
    inverted)."""
    if not hi > lo:
        raise ValueError(f"T_air_in grid needs hi > lo, got {lo:g} to {hi:g}")
    theta = np.asarray(theta, float)
    coarse = _steady_grid(model, u, theta[None], np.linspace(lo, hi, GRID_POINTS),
                          monotone=False)
    T_c = coarse.T_dryer_out[0]
    T_now = float(np.interp(float(u[_TA]), coarse.T_air_in, T_c))
    want = T_now + np.array([sp_lo, sp_hi]) - T_dryer_out_now
    # locating only: a dip of the coarse curve (a coarse tube at low T_air_in) must not stop
    # it; the fine grid, which the search reads, must rise
    ta = np.interp(want, np.maximum.accumulate(T_c) + 1e-9 * np.arange(T_c.size),
                   coarse.T_air_in)
    a = max(lo, min(ta[0], float(u[_TA])) - LOCAL_PAD)
    b = min(hi, max(ta[1], float(u[_TA])) + LOCAL_PAD)
    return _steady_grid(model, u, members(theta), np.linspace(a, b, LOCAL_POINTS))


@dataclass(frozen=True)
class Prediction:
    """The outlet moisture predicted at each candidate set point.

    Attributes
    ----------
    T_sp : ndarray (N,)
        Candidate set points. [K]
    T_air_in : ndarray (N,)
        Steady ``T_air_in`` the loop settles at (calibrated parameters; NaN beyond the
        grid). [K]
    mean, std : ndarray (N,)
        Predicted outlet moisture and its standard deviation (estimate's band and parameter
        covariance). [kg/kg]
    change_std : ndarray (N,)
        The parameters' part of ``std``: the standard deviation of the model's change. [kg/kg]
    """

    T_sp: np.ndarray
    T_air_in: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    change_std: np.ndarray


def predict(c: Curves, cov: np.ndarray, T_sp: np.ndarray, T_dryer_out_now: float,
            moisture_now: float, moisture_now_std: float) -> Prediction:
    """The outlet moisture at set points ``T_sp`` (module docstring): the estimate now plus
    the model's change, with the variance of both."""
    T_sp = np.asarray(T_sp, float)
    T_now, m_now = c.at(float(c.u[_TA]))
    target = T_now[:, None] + (T_sp[None, :] - T_dryer_out_now)  # (M, N) model outlet temps
    Ta = np.full(target.shape, np.nan)
    dm = np.full(target.shape, np.nan)
    for j in range(target.shape[0]):
        inside = (target[j] >= c.T_dryer_out[j, 0]) & (target[j] <= c.T_dryer_out[j, -1])
        Ta[j, inside] = np.interp(target[j, inside], c.T_dryer_out[j], c.T_air_in)
        dm[j, inside] = np.interp(Ta[j, inside], c.T_air_in, c.moisture_out[j]) - m_now[j]
    n = (dm.shape[0] - 1) // 2
    g = (dm[1::2][:n] - dm[2::2][:n]) / (2 * STEP)  # (7, N): d change / d ln(theta_i)
    var_theta = np.einsum("in,ij,jn->n", g, np.asarray(cov, float), g)
    std = np.sqrt(moisture_now_std**2 + np.maximum(var_theta, 0.0))
    return Prediction(T_sp, Ta[0], moisture_now + dm[0], std, np.sqrt(np.maximum(var_theta, 0)))


def settling_time(model: DryerModel, u_now: np.ndarray, u_new: np.ndarray, theta: np.ndarray,
                  fraction: float, horizon: float, dt: float = SETTLE_DT) -> float | None:
    """Time [s] the model's outlet moisture takes to come within ``fraction`` of the move
    from its new steady value after ``T_air_in`` steps from ``u_now`` to ``u_new`` (the loop
    taken as fast against the walls' heat-up, the slow part; see the explanation page);
    None when it has not settled within ``horizon``.

    The walls approach their new temperatures monotonically (first-order heat-up), so the
    first window within the tolerance is the settling time: the run stops there, one window
    at a time."""
    x, y0 = model.steady_state(u_now, theta)
    _, y1 = model.steady_state(u_new, theta)
    tol = fraction * abs(float(y1[_MO] - y0[_MO]))
    for k in range(max(int(math.ceil(horizon / dt)), 1)):
        x, y = model.step(x, u_new, theta, dt=dt)
        if abs(float(y[_MO] - y1[_MO])) <= tol:
            return (k + 1) * dt
    return None


__all__ = ["Curves", "Prediction", "curves", "heat_duty", "members", "per_tonne", "predict",
           "settling_time"]
