"""The open-loop estimator: the calibrated model fed the measured inputs, nothing else.

Each tick steps :class:`~softsensor.model.DryerModel` over the window with the window's measured
inputs and the config's nominal inlet moisture (``nominal.moisture_in``, 1.0 kg/kg for
``dryer1``): the paper's validation set-up, and the baseline the filter must beat. It has no
feedback, so it cannot know its own error: the standard deviations it reports are a fixed prior
from the config (``estimator.openloop_moisture_in_std``, ``estimator.openloop_moisture_out_std``),
not an estimate. Lab results are checked like the filter's (duplicates, the history's age)
but do not change the estimate; the next tick reports how far the model was from the lab at the
sample time (``lab_residual``), which is what a process engineer checks first.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from softsensor.errors import EstimationError, SoftsensorError
from softsensor.estimate import Estimate, Reason
from softsensor.estimation.interface import LabResult, ModelEstimator, Window, WindowModel
from softsensor.estimation.settings import EstimatorSettings
from softsensor.estimation.tick_history import LabBook
from softsensor.jsonable import finite_or_none
from softsensor.plantconfig import PlantConfig
from softsensor.signals import OUTPUT_NAMES
from softsensor.windows.inputs import MOISTURE_IN, InputHold

log = logging.getLogger(__name__)

_MO = OUTPUT_NAMES.index("moisture_out")
_CHECKPOINT_VERSION = 1


class OpenLoopEstimator(ModelEstimator):
    """The calibrated model run open loop with the nominal inlet moisture (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant configuration with calibrated parameter values.
    settings : EstimatorSettings, optional
        Overrides the config's ``[estimator]`` table.
    model : WindowModel, optional
        The model (default ``DryerModel(config)``).
    """

    kind = "openloop"

    def __init__(self, config: PlantConfig, settings: EstimatorSettings | None = None,
                 model: WindowModel | None = None) -> None:
        super().__init__(config, settings, model)
        self.moisture_in = float(config.nominal.moisture_in)
        self._hold = InputHold(config.nominal_inputs())
        self._wall: np.ndarray | None = None
        self._last_end: int | None = None
        #: (start_ns, end_ns, moisture_out) of the kept ticks, for lab residuals
        self._outputs: list[tuple[int, int, float]] = []
        self._residuals: list[tuple[str, float]] = []

    def tick(self, window: Window) -> Estimate:
        """Step the model over ``window`` and return the estimate."""
        if self._last_end is not None and window.end_ns <= self._last_end:
            raise EstimationError(f"window ending at {window.end_ns} ns is not after the last "
                                  f"tick ({self._last_end} ns)")
        self._last_end = window.end_ns
        u, held = self._hold.inputs(window)
        u[MOISTURE_IN] = self.moisture_in
        y = np.full(3, np.nan)
        detail = ""
        try:
            if self._wall is None:
                self._wall = self.model.steady_state(u, self.theta)[0]
            Y, wall = self.model.simulate(u[None, :], self.theta, state0=self._wall)
            self._wall, y = wall, Y[0]
        except SoftsensorError as exc:
            detail = f"model solve failed: {exc}"
        self._outputs.append((window.start_ns, window.end_ns, float(y[_MO])))
        keep = self.settings.history_ticks(self.window_s)
        del self._outputs[:-keep]
        self._labs.prune(self._outputs[0][0])
        for lab in self._labs.take_due(window.end_ns):
            self._residual(lab)
        residuals, self._residuals = self._residuals, []
        if window.stale:
            reason = Reason("stale", "stale window: open-loop model stepped on held inputs")
        elif detail:
            reason = Reason("degraded", detail)
        else:
            text = "open-loop model (no feedback); standard deviations are a fixed prior"
            if held:
                text += f"; holding last value of {', '.join(held)}"
            reason = Reason("ok", text)
        return Estimate(
            window_start_ns=int(window.start_ns), window_end_ns=int(window.end_ns),
            estimator=self.kind, moisture_out=finite_or_none(y[_MO]),
            moisture_out_std=self.settings.openloop_moisture_out_std,
            moisture_in=self.moisture_in, moisture_in_std=self.settings.openloop_moisture_in_std,
            T_dryer_out_model=finite_or_none(y[0]), T_cyclone_out_model=finite_or_none(y[1]),
            lab_updated=False, reasons=(reason,),
            lab_residual={sid: r for sid, r in residuals})

    def add_lab(self, lab: LabResult) -> str | None:
        """Validate ``lab`` (it never changes the open-loop estimate); reason when refused."""
        problem = self._screen_lab(lab)
        if problem:
            return problem
        if self._outputs and lab.sample_time_ns <= self._outputs[0][0]:
            return (f"lab {lab.sample_id!r}: sample time is older than the kept history "
                    f"({self.settings.history_hours:g} h); skipped")
        if self._last_end is None or lab.sample_time_ns > self._last_end:
            self._labs.add_pending(lab)
        else:
            self._residual(lab)
        return None

    def _residual(self, lab: LabResult) -> None:
        for start, end, mo in self._outputs:
            if start < lab.sample_time_ns <= end and math.isfinite(mo):
                self._residuals.append((lab.sample_id, lab.moisture_out - mo))
                return

    def checkpoint(self) -> dict[str, Any]:
        """JSON-able snapshot: wall state, held inputs, recent outputs, labs."""
        return {"kind": self.kind, "version": _CHECKPOINT_VERSION,
                "wall": None if self._wall is None else self._wall.tolist(),
                "hold": self._hold.last.tolist(), "last_end": self._last_end,
                "outputs": [[a, b, finite_or_none(c)] for a, b, c in self._outputs],
                "labs": self._labs.to_json(),
                "residuals": [list(r) for r in self._residuals]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from :meth:`checkpoint` output; EstimationError if it does not fit."""
        self._check_snapshot(snapshot, _CHECKPOINT_VERSION)
        try:
            wall = snapshot["wall"]
            self._wall = None if wall is None else np.array(wall, float)
            self._hold = InputHold(np.array(snapshot["hold"], float))
            last = snapshot["last_end"]
            self._last_end = None if last is None else int(last)
            self._outputs = [(int(a), int(b), math.nan if c is None else float(c))
                             for a, b, c in snapshot["outputs"]]
            self._labs = LabBook.from_json(snapshot["labs"])
            self._residuals = [(str(a), float(b)) for a, b in snapshot["residuals"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise EstimationError(f"checkpoint is malformed: {exc!r}") from exc
