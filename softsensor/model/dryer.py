"""The dryer model's one front door: steady state, one window, many windows, profiles.

One API serves the virtual plant, calibration, the filter and diagnosis. Every call takes a
batch: inputs ``u`` of shape ``(..., 8)`` in :data:`softsensor.signals.INPUT_NAMES` order,
parameters ``theta`` of shape ``(..., 7)`` in :data:`softsensor.plantconfig.PARAMETER_NAMES`
order, and states of shape ``(..., n_state)`` (the slow wall and shell temperatures, layout in
:mod:`softsensor.model.geometry`); leading axes broadcast against each other. Outputs have
shape ``(..., 3)`` in :data:`softsensor.signals.OUTPUT_NAMES` order: ``T_dryer_out`` [K],
``T_cyclone_out`` [K], ``moisture_out`` [kg/kg]. Outputs of a window are the values at its
end.

Example
-------
>>> from softsensor.model import DryerModel
>>> from softsensor.plantconfig import load_plant_config
>>> m = DryerModel(load_plant_config())           # the reference plant dryer1
>>> u = m.nominal_inputs()                        # (8,)
>>> x0, y0 = m.steady_state(u, m.theta0)          # consistent initial state
>>> x1, y1 = m.step(x0, u, m.theta0)              # one 600 s window

Batch members run in parallel threads, one per core (``DryerModel(threads=...)``); each member
gets exactly the numbers it gets alone (see :func:`for_members`).
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable

import numpy as np

from softsensor.errors import SolverError
from softsensor.model import kernels
from softsensor.model.geometry import N_AUX, Geometry, geometry
from softsensor.model.march import BAD_INPUT, NEWTON_FAILED, OK, STEADY_FAILED
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import INPUT_NAMES

#: Lengths of the input and parameter axes (their one definition: the name tuples).
_N_U, _N_THETA = len(INPUT_NAMES), len(PARAMETER_NAMES)

_STATUS_TEXT = {
    NEWTON_FAILED: "the cell balances did not converge",
    BAD_INPUT: "inputs or parameters are not physical (non-finite, non-positive flow "
                       "or parameter)",
    STEADY_FAILED: "the steady wall temperatures did not converge",
}


def default_threads() -> int:
    """Cores this process may run on: the number of threads a batch runs in by default."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def for_members(run: Callable[[slice], None], n_members: int, threads: int) -> None:
    """Call ``run(members)`` on slices covering ``range(n_members)``, in up to ``threads``
    threads.

    The kernels release the GIL (``nogil``) and each call allocates its own scratch, so members
    run in parallel on the cores, and each member gets exactly the computation it gets alone:
    the same kernel on its own rows, whatever the schedule. Members are handed out one at a
    time (a hard member, e.g. one with many Newton fallbacks, does not hold up a fixed share),
    and the calling thread works too. A batch of one runs in the calling thread.

    Why Python threads and not numba's ``parallel=True``: numba's own ``workqueue`` threading
    layer (the one that needs nothing installed) aborts the whole process when two Python
    threads launch parallel kernels at once, as the service's estimator thread or Optuna's
    ``n_jobs`` would; the ``omp`` and ``tbb`` layers need the system's GNU OpenMP (not
    fork-safe) or the ``tbb`` package. Threads over ``nogil`` kernels need neither and may be
    used from any number of threads.
    """
    n_threads = min(threads, n_members)
    if n_threads <= 1:
        run(slice(0, n_members))
        return
    claim = itertools.count()  # next() on a count is atomic under the GIL
    errors: list[BaseException] = []

    def work() -> None:
        try:
            while not errors:
                b = next(claim)
                if b >= n_members:
                    return
                run(slice(b, b + 1))
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)

    helpers = [threading.Thread(target=work, name=f"dryer-member-{i}", daemon=True)
               for i in range(n_threads - 1)]
    for t in helpers:
        t.start()
    work()
    for t in helpers:
        t.join()
    if errors:
        raise errors[0]


class DryerModel:
    """The flash dryer tube plus cyclone of one plant (paper section 2).

    Parameters
    ----------
    config : PlantConfig
        Plant configuration, already loaded (the reference plant ``dryer1``:
        :func:`softsensor.plantconfig.load_plant_config` with no path).
    n_d : int, optional
        Number of tube cells (overrides ``tube.n_cells``), e.g. for grid-convergence studies.
    wall_substeps : int, optional
        Crank-Nicolson substeps of the wall per window (overrides ``solver.wall_substeps``).
    threads : int, optional
        Threads a batch's members run in (default: the cores this process may use,
        :func:`default_threads`); 1 runs them one after another in the calling thread, e.g.
        when the caller already runs several models at once.
    """

    def __init__(self, config: PlantConfig, *, n_d: int | None = None,
                 wall_substeps: int | None = None, threads: int | None = None) -> None:
        # handed its configuration: the model reads no file (the apps load the TOML)
        if not isinstance(config, PlantConfig):
            raise TypeError(f"DryerModel needs a PlantConfig, got {type(config).__name__}")
        self.config = config
        self.geometry: Geometry = geometry(self.config, n_d)
        self.window = float(self.config.solver.window)
        self.wall_substeps = int(wall_substeps or self.config.solver.wall_substeps)
        self.theta0 = self.config.parameter_vector()
        self.threads = default_threads() if threads is None else max(int(threads), 1)

    # ------------------------------------------------------------------ helpers
    @property
    def n_state(self) -> int:
        """Length of a state vector (tube wall cells plus cyclone shell cells)."""
        return self.geometry.n_state

    def nominal_inputs(self, **overrides: float) -> np.ndarray:
        """Input vector at the config's nominal operating point, with optional overrides."""
        values = dict(zip(INPUT_NAMES, self.config.nominal_inputs(), strict=True))
        unknown = set(overrides) - set(values)
        if unknown:
            raise ValueError(f"unknown input {sorted(unknown)[0]!r}")
        values.update(overrides)
        return np.array([values[n] for n in INPUT_NAMES], dtype=float)

    def _prepare(self, *arrays: np.ndarray | None, trailing: tuple[int, ...]):
        """Broadcast batch axes; return flat (B, n) copies and the batch shape."""
        arrs = [np.asarray(a, dtype=float) for a in arrays]
        for a, n in zip(arrs, trailing, strict=True):
            if a.ndim == 0 or a.shape[-1] != n:
                raise ValueError(f"expected last axis of length {n}, got shape {a.shape}")
        batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrs))
        flat = [np.ascontiguousarray(np.broadcast_to(a, batch + (n,)).reshape(-1, n))
                for a, n in zip(arrs, trailing, strict=True)]
        return flat, batch

    def _aux(self, aux: np.ndarray | None) -> np.ndarray:
        return np.zeros(N_AUX) if aux is None else np.asarray(aux, dtype=float)

    @staticmethod
    def _check(status: np.ndarray, u: np.ndarray, first: int = 0) -> None:
        """Raise for the first failed member; ``status[0]`` is batch member ``first``."""
        bad = np.flatnonzero(status != OK)
        if bad.size:
            b = int(bad[0])
            detail = ", ".join(f"{n}={v:.6g}" for n, v in zip(INPUT_NAMES, u[b], strict=True))
            raise SolverError(f"model solve failed for batch member {first + b}: "
                              f"{_STATUS_TEXT.get(int(status[b]), 'unknown failure')} ({detail})")

    def _steady(self, u: np.ndarray, theta: np.ndarray, aux: np.ndarray, states: np.ndarray,
                y: np.ndarray, status: np.ndarray) -> None:
        """:func:`kernels.steady_batch` on flat (B, n) arrays, members in parallel threads."""
        geo = self.geometry.packed
        for_members(lambda m: kernels.steady_batch(u[m], theta[m], aux[m], geo, states[m], y[m],
                                                   status[m]), u.shape[0], self.threads)

    # ------------------------------------------------------------------ API
    def steady_state(self, u: np.ndarray, theta: np.ndarray | None = None,
                     aux: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Consistent initial state: the steady state at constant inputs ``u``.

        Returns ``(state, y)`` with shapes ``(..., n_state)`` and ``(..., 3)``; raises
        :class:`~softsensor.errors.SolverError` when any member fails.
        """
        theta = self.theta0 if theta is None else theta
        (u2, th2, ax2), batch = self._prepare(u, theta, self._aux(aux),
                                              trailing=(_N_U, _N_THETA, N_AUX))
        B = u2.shape[0]
        states = np.empty((B, self.n_state))
        y = np.empty((B, 3))
        status = np.empty(B, dtype=np.int64)
        self._steady(u2, th2, ax2, states, y, status)
        self._check(status, u2)
        return states.reshape(batch + (self.n_state,)), y.reshape(batch + (3,))

    def step(self, state: np.ndarray, u: np.ndarray, theta: np.ndarray | None = None,
             aux: np.ndarray | None = None, dt: float | np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
        """Advance ``state`` over one window of ``dt`` seconds (default: the config's window;
        an array gives each batch member its own) with inputs ``u`` held constant; returns
        ``(new_state, y_end)``."""
        theta = self.theta0 if theta is None else theta
        dt = np.asarray(self.window if dt is None else dt, dtype=float)
        if not np.all(dt > 0):
            raise ValueError(f"dt must be > 0, got {dt}")
        (x2, u2, th2, ax2), batch = self._prepare(
            state, u, theta, self._aux(aux), trailing=(self.n_state, _N_U, _N_THETA, N_AUX))
        B = u2.shape[0]
        dt = np.ascontiguousarray(np.broadcast_to(dt, batch).reshape(B))
        y = np.empty((B, 3))
        status = np.empty(B, dtype=np.int64)
        x2 = x2.copy()  # the kernel advances states in place; inputs may be read-only views
        geo, n_sub = self.geometry.packed, self.wall_substeps
        for_members(lambda m: kernels.step_batch(x2[m], u2[m], th2[m], ax2[m], geo, dt[m], n_sub,
                                                 y[m], status[m]), B, self.threads)
        self._check(status, u2)
        return x2.reshape(batch + (self.n_state,)), y.reshape(batch + (3,))

    def _batched(self, U: np.ndarray, theta: np.ndarray | None, aux: np.ndarray | None,
                 state0: np.ndarray | None
                 ) -> tuple[tuple[int, ...], np.ndarray, np.ndarray, np.ndarray]:
        """The batch shape of :meth:`simulate`'s arguments and its inputs, parameters and aux
        broadcast to it and flattened to (B, K, ...), contiguous for the kernels."""
        theta = self.theta0 if theta is None else np.asarray(theta, float)
        U = np.asarray(U, float)
        if U.ndim < 2 or U.shape[-1] != len(INPUT_NAMES):
            raise ValueError(f"U must have shape (..., K, {len(INPUT_NAMES)}), got {U.shape}")
        K = U.shape[-2]
        if theta.ndim == 1 or theta.shape[-2:-1] != (K,) or theta.ndim < U.ndim:
            theta = np.expand_dims(theta, -2)
        aux = self._aux(aux)
        if aux.ndim == 1 or aux.ndim < U.ndim:
            aux = np.expand_dims(aux, -2)
        batch = np.broadcast_shapes(U.shape[:-2], theta.shape[:-2], aux.shape[:-2],
                                    () if state0 is None else np.shape(state0)[:-1])
        Ub = np.ascontiguousarray(np.broadcast_to(U, batch + (K, _N_U)).reshape(-1, K, _N_U))
        Tb = np.ascontiguousarray(
            np.broadcast_to(theta, batch + (K, _N_THETA)).reshape(-1, K, _N_THETA))
        Ab = np.ascontiguousarray(np.broadcast_to(aux, batch + (K, N_AUX)).reshape(-1, K, N_AUX))
        return batch, Ub, Tb, Ab

    def _start_states(self, Ub: np.ndarray, Tb: np.ndarray, Ab: np.ndarray,
                      state0: np.ndarray | None, batch: tuple[int, ...],
                      raise_on_failure: bool) -> tuple[np.ndarray, np.ndarray]:
        """Each member's initial state (``state0`` broadcast, or the steady state at its first
        window's inputs) and its solver status (a failed steady state: 350 K placeholders)."""
        B = Ub.shape[0]
        if state0 is not None:
            states = np.ascontiguousarray(
                np.broadcast_to(np.asarray(state0, float), batch + (self.n_state,))
                .reshape(-1, self.n_state)).copy()
            return states, np.zeros(B, dtype=np.int64)
        states = np.empty((B, self.n_state))
        y0 = np.empty((B, 3))
        status = np.empty(B, dtype=np.int64)
        self._steady(np.ascontiguousarray(Ub[:, 0]), np.ascontiguousarray(Tb[:, 0]),
                     np.ascontiguousarray(Ab[:, 0]), states, y0, status)
        if raise_on_failure:
            self._check(status, Ub[:, 0])
        states[status != OK] = 350.0
        return states, status

    def simulate(self, U: np.ndarray, theta: np.ndarray | None = None,
                 aux: np.ndarray | None = None, state0: np.ndarray | None = None,
                 dt: float | None = None, raise_on_failure: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
        """Run windows of piecewise-constant inputs.

        Parameters
        ----------
        U : array, shape (..., K, 8)
            Inputs per window.
        theta : array, shape (..., 7) or (..., K, 7)
            Parameters, constant or per window (e.g. a drifting multiplier). ``theta`` is read
            per window when it has as many axes as ``U`` and its second-to-last axis has length
            ``K``; to run ``B`` parameter sets over one input sequence, give ``U`` a leading
            batch axis (``U[None]`` with ``theta`` of shape ``(B, 7)``).
        aux : array, shape (..., N_AUX) or (..., K, N_AUX), optional
            Model-extension coefficients (see :mod:`softsensor.model.geometry`).
        state0 : array, shape (..., n_state), optional
            Initial state; by default the steady state at the first window's inputs (the
            paper's "consistent starting vector per trial").
        raise_on_failure : bool
            When False, a failed member returns NaN outputs from the failing window on
            (calibration treats that as an infeasible trial) instead of raising.

        Returns
        -------
        Y : array, shape (..., K, 3)
            Outputs at the end of each window.
        state : array, shape (..., n_state)
            State after the last window.
        """
        batch, Ub, Tb, Ab = self._batched(U, theta, aux, state0)
        states, status = self._start_states(Ub, Tb, Ab, state0, batch, raise_on_failure)
        B, K = Ub.shape[:2]
        failed0 = status != OK
        dt = self.window if dt is None else float(dt)
        Y = np.empty((B, K, 3))
        status2 = np.empty(B, dtype=np.int64)
        geo, n_sub = self.geometry.packed, self.wall_substeps
        for_members(lambda m: kernels.simulate_batch(states[m], Ub[m], Tb[m], Ab[m], geo, dt,
                                                     n_sub, Y[m], status2[m]), B, self.threads)
        Y[failed0] = np.nan
        status2[failed0] = status[failed0]
        if raise_on_failure and np.any(status2 != OK):
            b = int(np.flatnonzero(status2 != OK)[0])
            k = int(np.argmax(np.isnan(Y[b, :, 0])))
            self._check(status2[b:b + 1], Ub[b, k][None], first=b)
        return Y.reshape(batch + (K, 3)), states.reshape(batch + (self.n_state,))

    def profiles(self, state: np.ndarray, u: np.ndarray,
                 theta: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Axial profiles for one state and input vector (no batch).

        Returns arrays over the ``n_d + n_c`` cells (tube first, then cyclone): ``X_f``
        [kg/kg], ``T_f`` [K], ``Y_a`` [kg/kg], ``T_a`` [K], ``T_w`` [K] (wall, then shell),
        ``UA_w`` [W/K], ``T_a_wall`` [K] (the air temperature the wall sees, the weighted
        state of the tube's theta scheme: wall heat is ``UA_w (T_a_wall - T_w)``), and ``x``
        [m] (cell centres along the tube; cyclone cells continue past the tube end at unit
        spacing of their own).
        """
        theta = self.theta0 if theta is None else np.asarray(theta, float)
        state = np.asarray(state, float)
        u = np.asarray(u, float)
        prof = np.empty((6, self.n_state))
        status = kernels.profile_one(np.ascontiguousarray(state), np.ascontiguousarray(u),
                                     np.ascontiguousarray(theta), self.geometry.packed, prof)
        self._check(np.array([status]), u[None])
        dx = self.config.tube.length / self.geometry.n_d
        x = np.concatenate([(np.arange(self.geometry.n_d) + 0.5) * dx,
                            self.config.tube.length + np.arange(1, self.geometry.n_c + 1) * dx])
        return {"X_f": prof[0], "T_f": prof[1], "Y_a": prof[2], "T_a": prof[3],
                "T_w": state.copy(), "UA_w": prof[4], "T_a_wall": prof[5], "x": x}

    def control_stepper(self, dt: float) -> ControlStepper:
        """A stepper for one closed-loop plant at control steps of ``dt`` [s] (the virtual
        plant's): see :class:`ControlStepper`."""
        return ControlStepper(self, dt)


class ControlStepper:
    """One plant advanced at short control steps (tens of seconds), as a PLC's loop sees it.

    Each :meth:`advance` returns the outputs *now* (the profile at the current wall state),
    then moves the wall over ``dt`` with that profile frozen (:func:`kernels.advance_one`):
    one profile solve per step, its Newton iteration started from the previous step's
    profile, which the stepper keeps. Use :meth:`DryerModel.step` for model windows.
    """

    def __init__(self, model: DryerModel, dt: float) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.dt = float(dt)
        self._geo = model.geometry.packed
        self._prof = np.full((6, model.n_state), -1.0)  # no previous profile yet
        self._work = np.empty(4 * model.n_state)
        self._y = np.empty(3)

    def advance(self, state: np.ndarray, u: np.ndarray, theta: np.ndarray,
                aux: np.ndarray) -> np.ndarray:
        """Outputs ``(3,)`` at the current ``state`` (advanced in place by ``dt``) for inputs
        ``u`` (8,), parameters ``theta`` (7,) and extension coefficients ``aux`` (N_AUX,).
        Raises :class:`~softsensor.errors.SolverError` with the solver's reason."""
        st = kernels.advance_one(state, u, theta, aux, self._geo, self.dt, self._prof,
                                 self._work, self._y)
        if st != OK:
            DryerModel._check(np.array([st]), np.asarray(u, float)[None])
        return self._y.copy()


def parameter_index(name: str) -> int:
    """Position of a Table 1 parameter in a ``theta`` vector."""
    return PARAMETER_NAMES.index(name)
