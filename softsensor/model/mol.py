"""The full transient method of lines: the reference the fast model is checked against.

This is the model "as a first Python implementation of the paper would" write it (paper
section 2.1: "a large, stiff system of ordinary differential equations solved in Python
utilizing the Method of Lines", solver BDF): every cell of the tube (``n_d``) and of the
cyclone (``n_c``) carries all five states, fibre moisture ``X`` [kg/kg] and temperature
``T_f`` [K], air humidity ratio ``Y`` [kg/kg] and temperature ``T_a`` [K], wall (or cyclone
shell) temperature ``T_w`` [K], and :func:`scipy.integrate.solve_ivp` (BDF) integrates all
``5 (n_d + n_c)`` of them over the whole horizon, restarting at every window boundary because
the inputs are piecewise constant. By default the Jacobian is a dense finite-difference one
(one right-hand side per state and Jacobian); ``jac="sparse"`` passes the pattern of
:meth:`StateLayout.sparsity` instead, which groups columns and is much cheaper.

The right-hand side, :func:`derivatives`, is compiled by numba like the fast model's kernels
(``compiled=False`` runs the same source in the Python interpreter), so that the comparison
of the two (``benchmarks/model.py``) measures the reformulation, not the compiler. Its cell
rates are the compiled model's own (:func:`cell_physics.cell_rates`,
:func:`cell_physics.inflow_coefficients`, :func:`cell_physics.outside_conductance`,
:func:`cell_physics.inlet_air`), the drying-rate law of ``fiber.drying_law`` included
(:func:`cell_physics.drying_law`, dispatched on the law index in ``geo``), so at steady state
both reach the same algebraic equations
(the :mod:`~softsensor.model.cell_physics` module docstring lists them); what differs is only
the time integration: here every state is dynamic, there the fibre and air sit at their
quasi-steady profile and the wall is stepped by Crank-Nicolson.

Balances of cell ``i`` (inflow from cell ``i-1``, or from the inlet for ``i = 0``), energy in
enthalpy form with :func:`humid_air.enthalpy` and :func:`wood.enthalpy`::

  fibre water   M_f dX/dt   = m_f (X_in - X) - R
  air water     M_a dY/dt   = m_a (Y_in - Y) + R
  fibre energy  M_f dh_f/dt = m_f (h_f,in - h_f) + Q_af - R h_v(T_f)
  air energy    M_a dh_a/dt = m_a (h_a,in - h_a) - Q_af - UA_w (T_a - T_w) + R h_v(T_f)
  wall          C_w dT_w/dt = UA_w (T_a - T_w) - UA_out (T_w - T_amb)
                               + G (T_w,i-1 - 2 T_w,i + T_w,i+1)  (tube, adiabatic ends)
  shell         C_sh dT_sh/dt = UA_w (T_a - T_sh) - UA_out (T_sh - T_amb)  (cyclone)

Rates see the weighted state ``w s_i + (1 - w) s_in`` of :func:`cell_physics.space_weight` (a
theta scheme along the tube, ``w = 0.6``; ``w = 1`` in the stirred cyclone cells), including the air
temperature in ``UA_w (T_a - T_w)`` and the fibre temperature in ``h_v``.

with ``dh_f = c_f dT_f + (dh_f/dX) dX`` (``c_f`` from :func:`wood.heat_capacity`, which is
``dh_f/dT``) and ``dh_a = c_a dT_a + h_v(T_a) dY`` (ASHRAE eq. 32), which turn the energy
balances into ``dT_f/dt`` and ``dT_a/dt``. ``R``, ``Q_af`` and the hold-ups ``M_f``, ``M_a``
come from :func:`cell_physics.cell_rates`; ``G = mult_k k_w A_cross / dx``.

The outside conductance ``UA_out`` is evaluated at the current wall temperature here; the fast
model evaluates it at the start of each wall substep (one of the small differences the
comparison measures).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numba import njit
from numba.extending import register_jitable
from scipy.integrate import solve_ivp
from scipy.sparse import lil_matrix

from softsensor.errors import SolverError
from softsensor.model import cell_physics as cell
from softsensor.model import humid_air as ha
from softsensor.model import wood as wd
from softsensor.model.dryer import DryerModel
from softsensor.model.geometry import C_SH_CELL, C_W_CELL, G_COND, N_AUX, X_FSP
from softsensor.signals import INPUT_NAMES

_FIELDS = ("X", "T_f", "Y", "T_a", "T_w")


@dataclass(frozen=True)
class StateLayout:
    """Where each state lives in the method-of-lines vector (defined here and nowhere else).

    The vector is field-major: ``[X[0..n-1], T_f[...], Y[...], T_a[...], T_w[...]]`` with
    ``n = n_d + n_c`` cells, tube first, then cyclone; ``T_w`` of a cyclone cell is its shell.
    """

    n_d: int
    n_c: int

    @property
    def n_cells(self) -> int:
        return self.n_d + self.n_c

    @property
    def size(self) -> int:
        return 5 * self.n_cells

    def field(self, name: str) -> slice:
        """Slice of one field (``X``, ``T_f``, ``Y``, ``T_a`` or ``T_w``) over all cells."""
        k = _FIELDS.index(name)
        return slice(k * self.n_cells, (k + 1) * self.n_cells)

    def index(self, name: str, cell: int) -> int:
        """Position of field ``name`` of ``cell`` in the vector."""
        return _FIELDS.index(name) * self.n_cells + cell

    def pack(self, X, T_f, Y, T_a, T_w) -> np.ndarray:
        """One vector from the five per-cell arrays."""
        return np.concatenate([np.asarray(a, float) for a in (X, T_f, Y, T_a, T_w)])

    def sparsity(self):
        """Jacobian pattern (``size x size``, sparse): cell ``i`` depends on itself and on
        the cell upstream (all five fields), the tube wall also on both wall neighbours."""
        n = self.n_cells
        S = lil_matrix((self.size, self.size), dtype=np.int8)
        for i in range(n):
            for fa in _FIELDS:
                row = self.index(fa, i)
                for fb in _FIELDS:
                    S[row, self.index(fb, i)] = 1
                    if i > 0:
                        S[row, self.index(fb, i - 1)] = 1
            if i < self.n_d:
                row = self.index("T_w", i)
                if i > 0:
                    S[row, self.index("T_w", i - 1)] = 1
                if i < self.n_d - 1:
                    S[row, self.index("T_w", i + 1)] = 1
        return S.tocsr()


@register_jitable
def _dh_f_dX(X: float, T_f: float, X_fsp: float) -> float:
    """``dh_f/dX`` at constant ``T_f`` [J/kg dry fibre per kg/kg], central difference."""
    h = 1e-6
    return (wd.enthalpy(X + h, T_f, X_fsp) - wd.enthalpy(X - h, T_f, X_fsp)) / (2.0 * h)


@njit(cache=True, nogil=True)
def derivatives(y, u, theta, aux, geo, n_d, dy):
    """``dy/dt`` of the method of lines into ``dy`` (module docstring's balances).

    ``y``, ``dy``: the :class:`StateLayout` vector of ``n = len(y) // 5`` cells, ``n_d`` of
    them tube; ``u`` (8,), ``theta`` (7,), ``aux`` (N_AUX,), ``geo`` the packed geometry.
    Compiled (numba, releases the GIL); ``derivatives.py_func`` is the same source run by the
    Python interpreter, which :class:`MethodOfLines` uses with ``compiled=False``.
    """
    n = y.shape[0] // 5
    m_a = u[cell.U_MAIR]
    m_f = u[cell.U_MFIB]
    T_amb = u[cell.U_TAMB]
    x_fsp = geo[X_FSP]
    G = theta[cell.K_K] * geo[G_COND]
    # inflow of cell 0: the inlet streams
    Y_in, h_a_in = cell.inlet_air(u, geo)
    X_in = u[cell.U_XIN]
    Ta_in = u[cell.U_TAIR]
    Tf_in = u[cell.U_TFIB]
    h_f_in = wd.enthalpy(X_in, Tf_in, x_fsp)
    for i in range(n):
        # field-major: X, T_f, Y, T_a, T_w of cell i (StateLayout)
        X, Tf, Y, Ta, Tw = y[i], y[n + i], y[2 * n + i], y[3 * n + i], y[4 * n + i]
        kind = 0 if i < n_d else 1
        w = cell.space_weight(kind)  # theta scheme in the tube, stirred tank in cyclone
        v_s, UAw = cell.inflow_coefficients(kind, Ta_in, Y_in, X_in, m_a, theta, geo)
        Tf_m = w * Tf + (1.0 - w) * Tf_in
        Ta_m = w * Ta + (1.0 - w) * Ta_in
        R, Q, M_f, M_a = cell.cell_rates(kind, w * X + (1.0 - w) * X_in, Tf_m,
                                            w * Y + (1.0 - w) * Y_in, Ta_m, v_s, m_a, m_f,
                                            theta, geo)
        h_f = wd.enthalpy(X, Tf, x_fsp)
        h_a = ha.enthalpy(Ta, Y)
        h_v = ha.vapour_enthalpy(Tf_m)
        Q_w = UAw * (Ta_m - Tw)
        dX = (m_f * (X_in - X) - R) / M_f
        dY = (m_a * (Y_in - Y) + R) / M_a
        dhf = (m_f * (h_f_in - h_f) + Q - R * h_v) / M_f
        dha = (m_a * (h_a_in - h_a) - Q - Q_w + R * h_v) / M_a
        dy[i] = dX
        dy[n + i] = (dhf - _dh_f_dX(X, Tf, x_fsp) * dX) / wd.heat_capacity(X, Tf, x_fsp)
        dy[2 * n + i] = dY
        dy[3 * n + i] = (dha - ha.vapour_enthalpy(Ta) * dY) / ha.heat_capacity(Ta, Y)
        U_out = cell.outside_conductance(Tw, u, theta, aux, geo, kind)
        wall = Q_w - U_out * (Tw - T_amb)
        if kind == 0:
            if i > 0:
                wall += G * (y[4 * n + i - 1] - Tw)
            if i < n_d - 1:
                wall += G * (y[4 * n + i + 1] - Tw)
            dy[4 * n + i] = wall / geo[C_W_CELL]
        else:
            dy[4 * n + i] = wall / geo[C_SH_CELL]
        X_in, Y_in, Ta_in, Tf_in, h_f_in, h_a_in = X, Y, Ta, Tf, h_f, h_a


class MethodOfLines:
    """Right-hand side of the full transient model for one plant geometry.

    Parameters
    ----------
    model : DryerModel
        Supplies the geometry (``n_d``, ``n_c``, packed constants) and the consistent start.
    compiled : bool
        Evaluate :func:`derivatives` compiled (default), or its source interpreted by Python
        (``derivatives.py_func``: the same arithmetic, 100s of times slower).
    """

    def __init__(self, model: DryerModel, compiled: bool = True) -> None:
        self.model = model
        self.geo = model.geometry.packed
        self.layout = StateLayout(model.geometry.n_d, model.geometry.n_c)
        self.compiled = compiled
        self._derivatives = derivatives if compiled else derivatives.py_func
        self.nfev = 0

    def rhs(self, t: float, y: np.ndarray, u: np.ndarray, theta: np.ndarray,
            aux: np.ndarray) -> np.ndarray:
        """``dy/dt`` for inputs ``u`` (8,), parameters ``theta`` (7,), extension ``aux``."""
        self.nfev += 1
        dy = np.empty(self.layout.size)
        self._derivatives(np.ascontiguousarray(y, dtype=float), u, theta, aux, self.geo,
                          self.layout.n_d, dy)
        return dy

    def outputs(self, y: np.ndarray) -> np.ndarray:
        """``(T_dryer_out, T_cyclone_out, moisture_out)`` of a state vector."""
        L = self.layout
        return np.array([y[L.index("T_a", L.n_d - 1)], y[L.index("T_a", L.n_cells - 1)],
                         y[L.index("X", L.n_cells - 1)]])

    def atol(self) -> np.ndarray:
        """Absolute tolerances per state: 1e-7 kg/kg for moistures, 1e-4 K for temperatures."""
        L = self.layout
        a = np.empty(L.size)
        for f in _FIELDS:
            a[L.field(f)] = 1e-7 if f in ("X", "Y") else 1e-4
        return a


@dataclass
class MolResult:
    """Outcome of :func:`simulate_mol`."""

    Y: np.ndarray          # (K, 3) outputs at the end of each window
    state: np.ndarray      # full method-of-lines vector after the last window
    nfev: int              # right-hand side evaluations, including those for Jacobians
    njev: int              # Jacobian evaluations
    nlu: int               # LU decompositions
    seconds: float         # wall-clock time of the integration (start state excluded)


def initial_vector(model: DryerModel, u: np.ndarray, theta: np.ndarray,
                   aux: np.ndarray | None = None, state0: np.ndarray | None = None
                   ) -> np.ndarray:
    """Full state from the fast model: its steady state at ``u`` (or ``state0``) and the
    quasi-steady fibre and air profile for those wall temperatures."""
    if state0 is None:
        state0, _ = model.steady_state(u, theta, aux)
    p = model.profiles(state0, u, theta)
    return StateLayout(model.geometry.n_d, model.geometry.n_c).pack(
        p["X_f"], p["T_f"], p["Y_a"], p["T_a"], p["T_w"])


def _checked_inputs(model: DryerModel, U: np.ndarray, theta: np.ndarray | None,
                    aux: np.ndarray | None, jac: str
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``U`` (K, 8), ``theta`` per window (K, 7) and ``aux`` (N_AUX,) of :func:`simulate_mol`,
    validated (the compiled right-hand side does not check bounds)."""
    U = np.atleast_2d(np.asarray(U, float))
    if U.shape[-1] != len(INPUT_NAMES) or U.ndim != 2:
        raise ValueError(f"U must have shape (K, {len(INPUT_NAMES)}), got {U.shape}")
    theta = model.theta0 if theta is None else np.asarray(theta, float)
    TH = np.ascontiguousarray(np.broadcast_to(theta, (U.shape[0], 7)))
    aux = np.zeros(N_AUX) if aux is None else np.asarray(aux, float)
    if aux.shape != (N_AUX,):
        raise ValueError(f"aux must have shape ({N_AUX},), got {aux.shape}")
    if not (np.all(np.isfinite(U)) and np.all(np.isfinite(TH))):
        bad = INPUT_NAMES[int(np.flatnonzero(~np.isfinite(U).all(axis=0))[0])] \
            if not np.all(np.isfinite(U)) else "theta"
        raise SolverError(f"method of lines: {bad} is not finite")
    if jac not in ("dense", "sparse"):
        raise ValueError(f"jac must be 'dense' or 'sparse', got {jac!r}")
    return U, TH, aux


def simulate_mol(model: DryerModel, U: np.ndarray, theta: np.ndarray | None = None,
                 aux: np.ndarray | None = None, y0: np.ndarray | None = None,
                 dt: float | None = None, jac: str = "dense", rtol: float = 1e-6,
                 compiled: bool = True) -> MolResult:
    """Integrate the full method of lines over windows of piecewise-constant inputs.

    Parameters
    ----------
    model : DryerModel
        Geometry, window length and the consistent start.
    U : array, shape (K, 8)
        Inputs per window, :data:`~softsensor.signals.INPUT_NAMES` order.
    theta : array, shape (7,) or (K, 7), optional
        Parameters (default ``model.theta0``).
    aux : array, shape (N_AUX,), optional
        Model-extension coefficients (see :mod:`softsensor.model.geometry`).
    y0 : array, shape (5 (n_d + n_c),), optional
        Full start vector; by default the fast model's steady state at ``U[0]``.
    dt : float, optional
        Window length [s] (default the config's, 600 s).
    jac : {"dense", "sparse"}
        Dense finite-difference Jacobian (the straightforward way) or the pattern of
        :meth:`StateLayout.sparsity`.
    rtol : float
        Relative tolerance of BDF; absolute ones from :meth:`MethodOfLines.atol`.
    compiled : bool
        Right-hand side compiled (default) or interpreted (:class:`MethodOfLines`).

    Raises
    ------
    SolverError
        When BDF fails in a window (with the solver's message) or the inputs are not finite.
    """
    U, TH, aux = _checked_inputs(model, U, theta, aux, jac)
    K = U.shape[0]
    dt = model.window if dt is None else float(dt)
    mol = MethodOfLines(model, compiled)
    y = initial_vector(model, U[0], TH[0], aux) if y0 is None else np.asarray(y0, float).copy()
    sparsity = mol.layout.sparsity() if jac == "sparse" else None
    atol = mol.atol()
    Y = np.empty((K, 3))
    njev = nlu = 0
    t0 = time.perf_counter()
    for k in range(K):
        try:
            sol = solve_ivp(mol.rhs, (0.0, dt), y, method="BDF", args=(U[k], TH[k], aux),
                            rtol=rtol, atol=atol, jac_sparsity=sparsity)
        except (ArithmeticError, ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
            # e.g. SuperLU's "Factor is exactly singular" on a non-finite Jacobian
            raise SolverError(f"method of lines failed in window {k} "
                              f"(t = {k * dt:.0f} s): {exc}") from exc
        if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
            raise SolverError(f"method of lines failed in window {k} "
                              f"(t = {k * dt:.0f} s): {sol.message}")
        y = sol.y[:, -1].copy()
        njev += sol.njev
        nlu += sol.nlu
        Y[k] = mol.outputs(y)
    return MolResult(Y=Y, state=y, nfev=mol.nfev, njev=njev, nlu=nlu,
                     seconds=time.perf_counter() - t0)
