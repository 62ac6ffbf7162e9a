"""The estimator interface: what the estimator service calls every 600 s tick.

A source (Modbus poller, MCAP replay, virtual plant) publishes scans; the service averages the
good scans of each window into a :class:`Window` and hands it to an :class:`Estimator`, which
returns the tick's :class:`~softsensor.estimate.Estimate` (CONTRACT section 2). Lab results reach
the estimator through :meth:`Estimator.add_lab` whenever they arrive, possibly long after their
sample time. Estimators are pure: no I/O, no clocks; time is whatever the window says.
"""

from __future__ import annotations

import logging
from typing import Any, Protocol

import numpy as np

from softsensor.errors import EstimationError
from softsensor.estimate import Estimate
from softsensor.estimation.settings import EstimatorSettings, estimator_settings
from softsensor.estimation.tick_history import LabBook
from softsensor.messages import LabResult, Window
from softsensor.plantconfig import PlantConfig

__all__ = ["Estimator", "LabResult", "ModelEstimator", "Window", "WindowModel"]

log = logging.getLogger(__name__)


class Estimator(Protocol):
    """What the estimator service needs from an estimator."""

    def tick(self, window: Window) -> Estimate:
        """Advance to ``window.end_ns`` and return the tick's estimate (the service finishes
        it with the window's facts, :func:`softsensor.service.estimator_service.finish`)."""
        ...

    def add_lab(self, lab: LabResult) -> str | None:
        """Queue a lab result; return ``None`` when accepted, else the reason it was refused."""
        ...

    def checkpoint(self) -> dict[str, Any]:
        """A JSON-serialisable snapshot from which :meth:`restore` resumes the same estimate."""
        ...

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from a snapshot written by :meth:`checkpoint`."""
        ...


class WindowModel(Protocol):
    """What an estimator needs from a model (:class:`softsensor.model.DryerModel` has it)."""

    theta0: np.ndarray
    window: float

    def steady_state(self, u: np.ndarray, theta: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray]: ...

    def simulate(self, U: np.ndarray, theta: np.ndarray | None = None,
                 aux: np.ndarray | None = None, state0: np.ndarray | None = None,
                 dt: float | None = None, raise_on_failure: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]: ...


class ModelEstimator:
    """What every model-based estimator holds: its plant configuration, its settings (the
    config's ``[estimator]`` table unless given), the model (``DryerModel(config)`` unless
    given; tests pass others), the model's parameters and its window length [s]."""

    #: The estimator's name in its estimate bodies and checkpoints.
    kind: str = ""

    def __init__(self, config: PlantConfig, settings: EstimatorSettings | None = None,
                 model: WindowModel | None = None) -> None:
        if model is None:
            from softsensor.model import DryerModel
            model = DryerModel(config)
        self.config = config
        self.settings = settings if settings is not None else estimator_settings(config)
        self.model = model
        self.theta = np.asarray(model.theta0, float)
        self.window_s = float(model.window)
        self._labs = LabBook()

    def _screen_lab(self, lab: LabResult) -> str | None:
        """The reason ``lab`` is refused (outside the plant lab's envelope, or a duplicate
        ``sample_id``), or ``None`` after remembering its id; needs the estimator's ``_labs``
        (:class:`~.tick_history.LabBook`). A :class:`LabResult` holds the lab-result contract
        of :mod:`softsensor.messages` (any dryer); the envelope is this plant's
        (``estimator.lab_envelope_min/max``), and what the estimator adds beyond it is the
        history's age and its statistical gate."""
        s = self.settings
        if not s.lab_envelope_min <= lab.moisture_out <= s.lab_envelope_max:
            # not remembered: the corrected result may come under the same sample id
            return (f"lab {lab.sample_id!r}: moisture_out {lab.moisture_out:g} kg/kg is outside "
                    f"the plant lab's envelope {s.lab_envelope_min:g}..{s.lab_envelope_max:g} "
                    f"kg/kg (estimator.lab_envelope_min/max); refused")
        if self._labs.is_duplicate(lab):
            return f"lab {lab.sample_id!r}: duplicate sample_id, ignored"
        self._labs.remember(lab)
        return None

    def _check_snapshot(self, snapshot: dict[str, Any], version: int) -> None:
        """:class:`EstimationError` unless ``snapshot`` is a checkpoint of this kind and
        ``version``."""
        if snapshot.get("kind") != self.kind or snapshot.get("version") != version:
            raise EstimationError(f"checkpoint is of kind {snapshot.get('kind')!r} version "
                                  f"{snapshot.get('version')!r}, expected {self.kind!r} "
                                  f"version {version}")
