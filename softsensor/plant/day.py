"""A simulated plant day in memory, shared by every plant simulator (no model import).

:class:`SimulatedDay` holds the frames a recorded day gives
(:func:`~softsensor.recording.mcap_day.read_day` returns the same shapes) plus the ground truth and
what was injected; :meth:`SimulatedDay.write` records it as an MCAP day (CONTRACT section 2) with
the ground truth on ``/truth/plant`` and the injected effect on ``/truth/effect``. Both the matched
plant (:mod:`softsensor.plant.simulator`) and the independent plant
(:mod:`softsensor.plant.independent`) return it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from softsensor.signals import TOPIC_LAB, TOPIC_SCAN, TOPIC_TRUTH

#: Default start of a simulated day: 2026-01-05 00:00:00 UTC [ns].
DEFAULT_START_NS = 1_767_571_200_000_000_000
TOPIC_TRUTH_EFFECT = "/truth/effect"


#: A schedule of knob moves a plant can follow: ``(t [s from the start], T_sp [K],
#: m_air [kg/s])``, as :mod:`softsensor.calibration.experiment_design` proposes.
KnobSchedule = tuple[np.ndarray, np.ndarray, np.ndarray]


def apply_schedule(t: np.ndarray, m_air: np.ndarray, nominal_m_air: float,
                   schedule: KnobSchedule) -> tuple[np.ndarray, np.ndarray]:
    """The set point [K] and fan flow [kg/s] of a day that follows ``schedule``: the
    schedule's ``T_sp`` held past its end, its ``m_air`` times the day's own relative wander
    (the fan still wanders around the flow the operator sets)."""
    ts, T_sp, m = (np.asarray(a, float) for a in schedule)
    return np.interp(t, ts, T_sp), np.interp(t, ts, m) * (np.asarray(m_air) / nominal_m_air)


@dataclass
class SimulatedDay:
    """A simulated day in memory (the same frames :func:`~softsensor.recording.mcap_day.read_day`
    returns).

    ``scans`` is indexed by log time [ns] with one column per scan signal; ``labs`` has
    ``log_time_ns, sample_time_ns, moisture_out, sample_id``; ``truth`` is indexed like
    ``scans`` with the true ``moisture_in``, ``moisture_out``, ``T_air_in``, ``T_dryer_out``,
    ``T_cyclone_out``, ``m_fiber`` (a plant may add columns); ``effect`` says what was
    injected.
    """

    scans: pd.DataFrame
    labs: pd.DataFrame
    truth: pd.DataFrame
    effect: dict[str, Any] = field(default_factory=dict)

    def write(self, path: str | Path) -> Path:
        """Write the day as an MCAP file (CONTRACT section 2); returns the path."""
        from softsensor.recording.day_writer import DayWriter  # adapter at the edge

        path = Path(path)
        start = int(self.scans.index[0])
        labs = self.labs.sort_values("log_time_ns").to_dict("records")
        j = 0
        scan_cols = list(self.scans.columns)
        scan_vals = self.scans.to_numpy()
        truth_cols = list(self.truth.columns)
        truth_vals = self.truth.to_numpy()
        with DayWriter(path) as w:
            w.write(TOPIC_TRUTH_EFFECT, start, self.effect)
            for i, t in enumerate(self.scans.index.to_numpy()):
                t = int(t)
                while j < len(labs) and labs[j]["log_time_ns"] <= t:
                    lab = labs[j]
                    w.write(TOPIC_LAB, int(lab["log_time_ns"]), {
                        "sample_time_ns": int(lab["sample_time_ns"]),
                        "moisture_out": round(float(lab["moisture_out"]), 5),
                        "sample_id": str(lab["sample_id"])})
                    j += 1
                body = {c: (None if math.isnan(v) else round(float(v), 6))
                        for c, v in zip(scan_cols, scan_vals[i], strict=True)}
                w.write(TOPIC_SCAN, t, body)
                w.write(TOPIC_TRUTH, t, {c: round(float(v), 6)
                                         for c, v in zip(truth_cols, truth_vals[i], strict=True)})
        return path
