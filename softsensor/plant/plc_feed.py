"""Feeds the virtual plant to the simulated PLC, scan by scan, and its lab to a drop folder.

The day is simulated up front (:func:`~softsensor.plant.simulator.simulate_day` is fast) and
then served in order: each call of :meth:`PlantFeed.next_values` returns the next scan's SI
values, the way a PLC's process image changes once per scan. Lab results are written as JSON
files into a drop folder when the plant's clock passes their log time, as a LIMS export
would, for the daemon's lab input to pick up.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from softsensor.plant.day import SimulatedDay


class PlantFeed:
    """Serves a simulated day scan by scan; ``loop`` restarts it at the end."""

    def __init__(self, day: SimulatedDay, lab_dir: str | os.PathLike[str] | None = None,
                 loop: bool = True) -> None:
        self.day = day
        self.loop = loop
        self.lab_dir = Path(lab_dir) if lab_dir is not None else None
        if self.lab_dir is not None:
            self.lab_dir.mkdir(parents=True, exist_ok=True)
        self._rows = day.scans.to_dict("records")
        self._times = day.scans.index.to_numpy()
        self._labs = day.labs.sort_values("log_time_ns").to_dict("records")
        self._i = 0
        self._j = 0
        self.finished = False

    @property
    def plant_time_ns(self) -> int:
        """Log time of the scan served last [ns]."""
        return int(self._times[max(self._i - 1, 0)])

    def next_values(self) -> dict[str, float]:
        """SI values of the next scan (signals that were not read are left out)."""
        if self._i >= len(self._rows):
            if not self.loop:
                self.finished = True
                self._i = len(self._rows) - 1
            else:
                self._i = 0
                self._j = 0
        row = self._rows[self._i]
        t = int(self._times[self._i])
        self._i += 1
        self._drop_labs(t)
        return {k: float(v) for k, v in row.items() if not math.isnan(v)}

    def _drop_labs(self, t_ns: int) -> None:
        while self._j < len(self._labs) and self._labs[self._j]["log_time_ns"] <= t_ns:
            lab = self._labs[self._j]
            self._j += 1
            if self.lab_dir is None:
                continue
            body = {"sample_time_ns": int(lab["sample_time_ns"]),
                    "moisture_out": float(lab["moisture_out"]),
                    "sample_id": str(lab["sample_id"])}
            tmp = self.lab_dir / f".{lab['sample_id']}.json.tmp"
            tmp.write_text(json.dumps(body))
            tmp.replace(self.lab_dir / f"{lab['sample_id']}.json")  # atomic for the watcher
