"""Simulating calibration segments for a batch of parameter sets, chunk by chunk.

A trial's cost needs the model over the whole horizon of every segment. To prune hopeless
trials early (paper section 3.3), the horizon is cut into ``n_chunks`` consecutive chunks; the
model runs one chunk for every live batch member in one batched
:meth:`~softsensor.model.dryer.DryerModel.simulate` call, the end state is passed on as the
next chunk's ``state0``, and the partial cost (eq. 4 over the windows simulated so far) is
reported after each chunk. Members that are pruned are simply not simulated any further.

Every member starts from the steady state at its segment's first-window inputs and its own
parameters: the paper's "per trial" consistent initial state. A member whose solve fails gets
NaN outputs and an infinite cost (it is never raised: a bad corner of the search box is a bad
trial, not an error).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from softsensor.calibration.cost import Fit, evaluate_fit
from softsensor.calibration.dataset import Segment
from softsensor.model import DryerModel


def chunk_bounds(n_windows: int, n_chunks: int) -> np.ndarray:
    """Window indices ``0 = b_0 < b_1 < ... < b_n = n_windows`` of ``n_chunks`` near-equal
    chunks (fewer when the segment has fewer windows than chunks)."""
    n = max(1, min(int(n_chunks), int(n_windows)))
    return np.unique(np.round(np.linspace(0, n_windows, n + 1)).astype(int))


class ChunkedRun:
    """One batch of parameter sets advancing through every segment in lockstep chunks.

    Parameters
    ----------
    model : DryerModel
    segments : sequence of Segment
    theta : array, shape (B, 7)
        Parameter sets in :data:`~softsensor.plantconfig.PARAMETER_NAMES` order.
    weights : array, shape (3,)
        Eq. 4 weights in :data:`~softsensor.signals.OUTPUT_NAMES` order.
    n_chunks : int
        Chunks per segment (1: no intermediate costs).
    """

    def __init__(self, model: DryerModel, segments: Sequence[Segment], theta: np.ndarray,
                 weights: np.ndarray, n_chunks: int = 4) -> None:
        self.model = model
        self.segments = list(segments)
        self.theta = np.atleast_2d(np.asarray(theta, float))
        self.weights = np.asarray(weights, float)
        B = self.theta.shape[0]
        self.bounds = [chunk_bounds(s.n_windows, n_chunks) for s in self.segments]
        self.n_steps = max(len(b) - 1 for b in self.bounds)
        self.alive = np.ones(B, dtype=bool)
        self.failed = np.zeros(B, dtype=bool)
        self.Y = [np.full((B, s.n_windows, 3), np.nan) for s in self.segments]
        self.states: list[np.ndarray | None] = [None] * len(self.segments)
        self.step_index = 0

    @property
    def done(self) -> bool:
        return self.step_index >= self.n_steps

    def _upto(self, step: int) -> list[int]:
        return [int(b[min(step + 1, len(b) - 1)]) for b in self.bounds]

    def advance(self) -> dict[int, Fit]:
        """Simulate the next chunk for every live member; return their partial fits.

        The returned dict maps batch index to the eq. 4 fit over the windows simulated so far
        (``inf`` cost for a member whose solve failed; it is not simulated any further).
        """
        if self.done:
            raise RuntimeError("the run is complete")
        live = np.flatnonzero(self.alive)
        c = self.step_index
        for s, seg in enumerate(self.segments):
            b = self.bounds[s]
            if c + 1 >= len(b) or live.size == 0:
                continue
            k0, k1 = int(b[c]), int(b[c + 1])
            state0 = None if self.states[s] is None else self.states[s][live]
            # U gets a leading batch axis so theta (B, 7) is read as constant parameters
            Y, x_end = self.model.simulate(seg.U[k0:k1][None], self.theta[live],
                                           state0=state0, raise_on_failure=False)
            self.Y[s][live, k0:k1] = Y
            if self.states[s] is None:
                self.states[s] = np.full((self.theta.shape[0], x_end.shape[-1]), np.nan)
            self.states[s][live] = x_end
            failed = live[np.isnan(Y).any(axis=(1, 2))]
            self.failed[failed] = True
        self.alive[self.failed] = False
        self.step_index += 1
        return self.partial(live)

    def partial(self, members: np.ndarray | None = None) -> dict[int, Fit]:
        """Eq. 4 over the windows simulated so far, for ``members`` (default: the live ones)."""
        members = np.flatnonzero(self.alive) if members is None else np.asarray(members)
        if members.size == 0:
            return {}
        upto = self._upto(self.step_index - 1)
        fits = evaluate_fit([Y[members] for Y in self.Y], self.segments, self.weights, upto)
        return {int(m): f for m, f in zip(members, fits, strict=True)}

    def drop(self, member: int) -> None:
        """Stop simulating ``member`` (pruned)."""
        self.alive[member] = False

    def run(self) -> list[Fit]:
        """Run every remaining chunk without pruning; return the full-horizon fits."""
        while not self.done:
            self.advance()
        return evaluate_fit(self.Y, self.segments, self.weights)


def simulate_segments(model: DryerModel, segments: Sequence[Segment], theta: np.ndarray
                      ) -> list[np.ndarray]:
    """Model outputs ``(B, K_s, 3)`` (or ``(K_s, 3)`` for one ``theta`` of shape (7,)) on every
    segment, each from the steady state at its first window; NaN where the solve failed."""
    theta = np.asarray(theta, float)
    one = theta.ndim == 1
    out = []
    for seg in segments:
        Y, _ = model.simulate(seg.U[None], np.atleast_2d(theta), raise_on_failure=False)
        out.append(Y[0] if one else Y)
    return out


__all__ = ["ChunkedRun", "chunk_bounds", "simulate_segments"]
