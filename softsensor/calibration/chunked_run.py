"""Simulating calibration segments for a batch of parameter sets, chunk by chunk.

A trial's cost needs the model over the whole horizon of every segment. To prune hopeless
trials early (paper section 3.3), the horizon is cut into ``n_chunks`` consecutive chunks; the
model runs one chunk for every live batch member in one batched
:meth:`~softsensor.model.dryer.DryerModel.simulate` call, the end state is passed on as the
next chunk's ``state0``, and the partial cost (eq. 4 over the windows simulated so far) is
reported after each chunk. Members that are pruned are simply not simulated any further.

Every member starts from the steady state at its segment's first-window inputs and its own
parameters: the paper's "per trial" consistent initial state. Lab samples are evaluated at
their sample time (:mod:`.dataset`): the run is split at the start of every window holding a
sample, and from the state there one short step to the sample time with the sample's inputs
gives the model's ``moisture_out``. A member whose solve fails gets
NaN outputs and an infinite cost (it is never raised: a bad corner of the search box is a bad
trial, not an error).

When the objective estimates the inlet moisture (:mod:`.objective`), every parameter set runs
twice, as it is and with the inlet moisture raised (``du``, per-member input offsets), in the
same batched call.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence

import numpy as np

from softsensor.calibration.cost import ModelRun
from softsensor.calibration.dataset import LabPoints, Segment
from softsensor.calibration.objective import (
    Evaluation,
    ObjectiveSpec,
    evaluate,
    inlet_fitted_run,
    sensitivity_offsets,
)
from softsensor.errors import SoftsensorError
from softsensor.model import DryerModel


def chunk_bounds(n_windows: int, n_chunks: int) -> np.ndarray:
    """Window indices ``0 = b_0 < b_1 < ... < b_n = n_windows`` of ``n_chunks`` near-equal
    chunks (fewer when the segment has fewer windows than chunks)."""
    n = max(1, min(int(n_chunks), int(n_windows)))
    return np.unique(np.round(np.linspace(0, n_windows, n + 1)).astype(int))


def _lab_sample(model: DryerModel, u_sample: np.ndarray, u_window: np.ndarray, dt: float,
                theta: np.ndarray, aux: np.ndarray | None,
                state: np.ndarray | None) -> np.ndarray:
    """``moisture_out`` (B,) at a lab sample ``dt`` seconds into its window: one step from
    the window's start at the sample's inputs (B, 8), or, for the members where those fail,
    at the window's."""
    y, _ = model.simulate(u_sample[:, None], theta, aux=aux, state0=state, dt=dt,
                          raise_on_failure=False)
    out = y[:, 0, 2]
    bad = np.flatnonzero(np.isnan(out))
    if bad.size:  # the sample-time inputs failed: the window's inputs instead
        y, _ = model.simulate(u_window[bad][:, None], theta[bad], aux=aux, dt=dt,
                              state0=None if state is None else state[bad],
                              raise_on_failure=False)
        out[bad] = y[:, 0, 2]
    return out


def simulate_span(model: DryerModel, seg: Segment, theta: np.ndarray, k0: int, k1: int,
                  state0: np.ndarray | None, du: np.ndarray | None = None, *,
                  U: np.ndarray | None = None, aux: np.ndarray | None = None,
                  labs: LabPoints | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Windows ``k0 .. k1-1`` of ``seg`` for parameter sets ``theta``.

    Parameters
    ----------
    theta : array, shape (B, 7) or (B, K, 7)
        Parameter sets, constant or per window of the segment (a drifting multiplier).
    state0 : array, shape (B, n_state) or None
        State at the start of window ``k0`` (None: the steady state at that window's inputs).
    du : array, shape (B, 8), optional
        Offsets added to every input of each member (e.g. the inlet moisture raised).
    U : array, shape (K, 8), optional
        Inputs replacing the segment's (a model extension's view of them).
    aux : array, shape (N_AUX,) or (K, N_AUX), optional
        Model-extension coefficients, constant or per window.
    labs : LabPoints, optional
        Where the lab samples meet the model (default the segment's own,
        :meth:`Segment.default_lab_points`; :meth:`Segment.lab_points` moves them).

    Returns ``Y`` (B, k1-k0, 3), the model's ``moisture_out`` at the lab samples whose window
    lies in the span (B, n_labs), and the end state (B, n_state). Failed members give NaN,
    never an exception. Where the model cannot be solved at a sample's own inputs but can at
    its window's (the cell Newton of the model does not converge from every state), the
    window's inputs are used for it.
    """
    theta = np.asarray(theta, float)
    theta = theta[None] if theta.ndim == 1 else theta
    per_window = theta.ndim == 3
    B = theta.shape[0]
    U = seg.U if U is None else np.asarray(U, float)
    labs = seg.default_lab_points() if labs is None else labs
    aux = None if aux is None else np.asarray(aux, float)
    dU = np.zeros((B, U.shape[1])) if du is None else np.asarray(du, float)

    in_span = np.flatnonzero((labs.window >= k0) & (labs.window < k1))
    cuts = sorted({k0, k1, *(int(w) for w in labs.window[in_span] if w > k0)})
    Y = np.empty((B, k1 - k0, 3))
    lab = np.full((B, in_span.size), np.nan)
    state = state0
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        # parameters (B, 7) and aux of window a, for its lab samples
        th_a = theta[:, a] if per_window else theta
        aux_a = aux[a] if aux is not None and aux.ndim == 2 else aux
        for j, li in enumerate(in_span):
            if labs.window[li] == a:
                lab[:, j] = _lab_sample(model, labs.inputs[li] + dU, U[a] + dU,
                                        float(labs.offset[li]), th_a, aux_a, state)
        # U gets a leading batch axis so theta (B, 7) is read as constant parameters and
        # theta (B, K, 7) and aux (K, N_AUX) per window
        Ua = U[a:b][None] if du is None else U[a:b][None] + dU[:, None, :]
        th = theta[:, a:b] if per_window else theta
        ax = aux if aux is None or aux.ndim == 1 else aux[a:b][None]
        Yp, state = model.simulate(Ua, th, aux=ax, state0=state, raise_on_failure=False)
        Y[:, a - k0:b - k0] = Yp
    return Y, lab, state


def window_start_states(model: DryerModel, seg: Segment, theta: np.ndarray, *,
                        U: np.ndarray | None = None, aux: np.ndarray | None = None
                        ) -> np.ndarray:
    """The model's state at the start of every window of ``seg`` (K, n_state) for one
    parameter set ``theta`` (7,), from the steady state at the first window's inputs: what
    :func:`lab_values_at` steps from when the lab samples move (a lab time shift). Raises
    :class:`~softsensor.errors.SoftsensorError` when the model fails."""
    U = seg.U if U is None else np.asarray(U, float)
    aux = None if aux is None else np.asarray(aux, float)
    aux0 = aux if aux is None or aux.ndim == 1 else aux[0]
    state, _ = model.steady_state(U[0], theta, aux=aux0)
    out = np.empty((seg.n_windows, model.n_state))
    for k in range(seg.n_windows):
        out[k] = state
        ax = aux if aux is None or aux.ndim == 1 else aux[k]
        state, _ = model.step(state, U[k], theta, aux=ax)
    return out


def lab_values_at(model: DryerModel, states: np.ndarray, labs: LabPoints,
                  theta: np.ndarray) -> np.ndarray:
    """The model's ``moisture_out`` at lab points (L,), each one step of its offset from the
    state at the start of its window (``states`` from :func:`window_start_states`): the lab
    alignment of :func:`simulate_span`, for many sample times at once. NaN where the model
    fails."""
    if labs.window.size == 0:
        return np.zeros(0)
    x = states[labs.window]
    try:
        _, y = model.step(x, labs.inputs, theta, dt=labs.offset)
    except SoftsensorError:
        out = np.full(labs.window.size, np.nan)
        for i in range(labs.window.size):
            with contextlib.suppress(SoftsensorError):
                out[i] = model.step(x[i], labs.inputs[i], theta, dt=labs.offset[i])[1][2]
        return out
    return y[:, 2]


class ChunkedRun:
    """One batch of parameter sets advancing through every segment in lockstep chunks.

    Parameters
    ----------
    model : DryerModel
    segments : sequence of Segment
    theta : array, shape (B, 7)
        Parameter sets in :data:`~softsensor.plantconfig.PARAMETER_NAMES` order.
    spec : ObjectiveSpec
        What is scored (:mod:`.objective`); with an estimated inlet moisture every set also
        runs with the inlet moisture raised.
    n_chunks : int
        Chunks per segment (1: no intermediate costs).
    """

    def __init__(self, model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                 spec: ObjectiveSpec, n_chunks: int = 4) -> None:
        self.model = model
        self.segments = list(segments)
        self.theta = np.atleast_2d(np.asarray(theta, float))
        self.spec = spec
        B = self.theta.shape[0]
        self.du = sensitivity_offsets(B, spec.inlet is not None)
        self.members = self.theta if self.du is None else np.vstack([self.theta, self.theta])
        M = self.members.shape[0]
        self.bounds = [chunk_bounds(s.n_windows, n_chunks) for s in self.segments]
        self.n_steps = max(len(b) - 1 for b in self.bounds)
        self.alive = np.ones(B, dtype=bool)
        self.failed = np.zeros(B, dtype=bool)
        self.runs = [ModelRun(np.full((M, s.n_windows, 3), np.nan),
                              np.full((M, len(s.lab_value)), np.nan)) for s in self.segments]
        self.states: list[np.ndarray | None] = [None] * len(self.segments)
        self.step_index = 0

    @property
    def done(self) -> bool:
        return self.step_index >= self.n_steps

    def _upto(self, step: int) -> list[int]:
        return [int(b[min(step + 1, len(b) - 1)]) for b in self.bounds]

    def _rows(self, members: np.ndarray) -> np.ndarray:
        """Rows of the runs holding parameter sets ``members`` (both copies with the inlet)."""
        B = self.theta.shape[0]
        return members if self.du is None else np.concatenate([members, members + B])

    def advance(self) -> dict[int, Evaluation]:
        """Simulate the next chunk for every live member; return their partial evaluations.

        The returned dict maps batch index to the objective over the windows simulated so far
        (infinite for a member whose solve failed; it is not simulated any further).
        """
        if self.done:
            raise RuntimeError("the run is complete")
        live = np.flatnonzero(self.alive)
        rows = self._rows(live)
        c = self.step_index
        B = self.theta.shape[0]
        for s, seg in enumerate(self.segments):
            b = self.bounds[s]
            if c + 1 >= len(b) or live.size == 0:
                continue
            k0, k1 = int(b[c]), int(b[c + 1])
            state0 = None if self.states[s] is None else self.states[s][rows]
            Y, lab, x_end = simulate_span(self.model, seg, self.members[rows], k0, k1, state0,
                                          None if self.du is None else self.du[rows])
            run = self.runs[s]
            run.Y[rows, k0:k1] = Y
            span = (seg.lab_window >= k0) & (seg.lab_window < k1)
            run.lab[np.ix_(rows, np.flatnonzero(span))] = lab
            if x_end is not None:  # a stateless model (tests) has nothing to carry on
                if self.states[s] is None:
                    self.states[s] = np.full((self.members.shape[0], x_end.shape[-1]),
                                             np.nan)
                self.states[s][rows] = x_end
            bad = np.isnan(Y).any(axis=(1, 2)) | np.isnan(lab).any(axis=1)
            bad_sets = np.unique(rows[bad] % B) if self.du is not None else rows[bad]
            self.failed[bad_sets] = True
        self.alive[self.failed] = False
        self.step_index += 1
        return self.partial(live)

    def partial(self, members: np.ndarray | None = None) -> dict[int, Evaluation]:
        """The objective over the windows simulated so far, for ``members`` (default: the
        live ones)."""
        members = np.flatnonzero(self.alive) if members is None else np.asarray(members)
        if members.size == 0:
            return {}
        upto = self._upto(self.step_index - 1)
        base = [r.member(members) for r in self.runs]
        sens = None
        if self.du is not None:
            B = self.theta.shape[0]
            sens = [r.member(members + B) for r in self.runs]
        evs = evaluate(self.segments, base, sens, self.theta[members], self.spec, upto)
        return {int(m): e for m, e in zip(members, evs, strict=True)}

    def drop(self, member: int) -> None:
        """Stop simulating ``member`` (pruned)."""
        self.alive[member] = False

    def model_lines(self, member: int, ev: Evaluation) -> list[ModelRun]:
        """Parameter set ``member``'s outputs on every segment as two rows (a complete run):
        row 0 with ``ev``'s fitted inlet trajectory, what the cost compares (the measurements
        minus it are the residuals ``ev`` scores), row 1 with the nominal inlet moisture (open
        loop). Without an estimated inlet moisture both rows are the open-loop run."""
        B = self.theta.shape[0]
        out = []
        for s, (seg, run) in enumerate(zip(self.segments, self.runs, strict=True)):
            base = run.member(member)
            fitted = (base if self.du is None else
                      inlet_fitted_run(seg, base, run.member(member + B), ev.inlet[s],
                                       ev.knots[s]))
            out.append(ModelRun(np.concatenate([fitted.Y, base.Y]),
                                np.concatenate([fitted.lab, base.lab])))
        return out

    def run(self) -> list[Evaluation]:
        """Run every remaining chunk without pruning; return the full-horizon evaluations."""
        while not self.done:
            self.advance()
        B = self.theta.shape[0]
        ev = self.partial(np.arange(B))
        return [ev[b] for b in range(B)]


def simulate_segments(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                      du: np.ndarray | None = None) -> list[ModelRun]:
    """Model outputs on every segment for ``theta`` (7,) or (B, 7), each from the steady
    state at its first window; NaN where the solve failed. Always with a batch axis. ``du``
    (B, 8): per-member input offsets."""
    theta = np.atleast_2d(np.asarray(theta, float))
    out = []
    for seg in segments:
        Y, lab, _ = simulate_span(model, seg, theta, 0, seg.n_windows, None, du)
        out.append(ModelRun(Y, lab))
    return out


def evaluate_parameters(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                        spec: ObjectiveSpec) -> list[Evaluation]:
    """Simulate ``theta`` (7,) or (B, 7) on every segment and score it (:mod:`.objective`)."""
    return ChunkedRun(model, segments, theta, spec, n_chunks=1).run()


__all__ = ["ChunkedRun", "chunk_bounds", "evaluate_parameters", "lab_values_at",
           "simulate_segments", "simulate_span", "window_start_states"]
