"""From a :class:`~softsensor.messages.Window` to model inputs and measured outputs.

The model needs all seven measured inputs of :data:`softsensor.signals.INPUT_NAMES` every
window. A signal whose window mean is missing (sensor out, too few good scans) holds its last
good value; before any good value it takes the config's nominal value. ``moisture_in`` is not
measured: the estimator fills the last slot itself. The outlet temperatures are measurements;
a missing one is simply not used for correction that window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsensor.messages import Window
from softsensor.signals import INPUT_NAMES, KELVIN_CHANNELS

#: Measured model inputs (all but the unmeasured ``moisture_in``).
MEASURED_INPUTS: tuple[str, ...] = INPUT_NAMES[:-1]
#: Index of ``moisture_in`` in an input vector.
MOISTURE_IN = INPUT_NAMES.index("moisture_in")


def _good(value: float | None) -> bool:
    return value is not None and math.isfinite(value)


@dataclass
class InputHold:
    """Fills window inputs, holding the last good value of each measured input.

    Attributes
    ----------
    last : numpy.ndarray, shape (8,)
        Last input vector handed out, in ``INPUT_NAMES`` order (SI units); ``moisture_in`` is
        the nominal value and is overwritten by the estimators.
    """

    last: np.ndarray

    def inputs(self, window: Window) -> tuple[np.ndarray, list[str]]:
        """Input vector of ``window`` and the names of the inputs that were held."""
        u = self.last.copy()
        held = []
        for i, name in enumerate(MEASURED_INPUTS):
            v = window.means.get(name)
            if _good(v):
                u[i] = float(v)  # type: ignore[arg-type]
            else:
                held.append(name)
        self.last = u
        return u.copy(), held


@dataclass(frozen=True)
class TemperatureMeasurement:
    """The outlet temperatures measured in one window.

    Attributes
    ----------
    channels : tuple of int
        Indices into :data:`~softsensor.signals.OUTPUT_NAMES` of the channels present.
    values : numpy.ndarray
        Window means of those channels. [K]
    variances : numpy.ndarray
        Their noise variances: ``sensor_std**2 / n_good + model_std**2``. [K²]
    """

    channels: tuple[int, ...]
    values: np.ndarray
    variances: np.ndarray


def temperatures(window: Window, sensor_std: float, model_std: float) -> TemperatureMeasurement:
    """Measured outlet temperatures of ``window`` (none when the window is stale).

    The variance of a window mean of ``n`` good scans is ``sensor_std² / n`` (independent scan
    noise); ``model_std²`` adds the model's own error, which does not average out.
    """
    channels: list[int] = []
    values: list[float] = []
    variances: list[float] = []
    if not window.stale:
        for k, name in enumerate(KELVIN_CHANNELS):
            v = window.means.get(name)
            if not _good(v):
                continue
            n = max(int(window.n_good.get(name, window.n_scans)), 1)
            channels.append(k)
            values.append(float(v))  # type: ignore[arg-type]
            variances.append(sensor_std**2 / n + model_std**2)
    return TemperatureMeasurement(tuple(channels), np.array(values), np.array(variances))
