"""Transport delays, thermocouple lags, noise, missing reads and the laboratory.

* :class:`DelayLine`: values stamped with the time they *arrive* somewhere (the tube inlet,
  the tube outlet, the cyclone outlet); reading it at a time interpolates linearly between
  arrivals. The burner gas reaches the tube after the member's dead time; each output of the
  quasi-steady flow reaches its sensor after the flow's own transit time.
* :class:`FirstOrderLag`: a sheathed thermocouple is a first-order lag (Doebelin,
  *Measurement Systems*, 5th ed., sec. 3.3); discretised exactly for an input that is linear
  over the step (first-order hold).
* Noise: Gaussian, 0.5 K on temperatures, 1 % on flows, 2 % on humidity (the
  ``[virtual_plant]`` settings). A read fails (``None`` in the scan) with a small
  probability per signal and scan.
* Lab: :func:`lab_results`, a grab sample of the instantaneous outlet moisture every 2 to
  4 h, reported 20 to 90 min later with lab noise; with the ``lab_delay`` effect the stamped
  sample time is off by a fixed shift.
"""

from __future__ import annotations

import bisect
import math

import numpy as np
import pandas as pd

from softsensor.plant.settings import VirtualPlantSettings

#: Probability that one signal of one scan is not read.
P_MISSING = 1e-4


class DelayLine:
    """Values stamped with their arrival time [s]; before the first arrival the initial
    value holds."""

    def __init__(self, initial: float) -> None:
        self.t = [-math.inf]
        self.v = [float(initial)]
        self.cursor = 1  # reads move forward in time: search from the last one

    def push(self, arrival: float, value: float) -> None:
        # arrivals are monotone in practice; a late stamp (transit shrinking faster than the
        # step) is moved to just after the last one so the series stays a function of time
        if arrival <= self.t[-1]:
            arrival = self.t[-1] + 1e-6
        self.t.append(arrival)
        self.v.append(float(value))

    def at(self, time: float) -> float:
        """Value at ``time`` [s]: linear between the arrivals around it."""
        t = self.t
        n = len(t)
        i = self.cursor
        if i > n or (i > 1 and t[i - 1] > time):
            i = bisect.bisect_right(t, time)
        while i < n and t[i] <= time:
            i += 1
        self.cursor = i  # t[i-1] <= time < t[i]
        if i >= n:
            return self.v[-1]
        t0 = t[i - 1]
        if not math.isfinite(t0):
            return self.v[i - 1]
        w = (time - t0) / (t[i] - t0)
        return self.v[i - 1] + w * (self.v[i] - self.v[i - 1])


class FirstOrderLag:
    """First-order lag with time constant ``tau`` [s] (``tau`` 0: no lag)."""

    def __init__(self, tau: float, value: float) -> None:
        self.tau = tau
        self.y = value
        self.u = value

    def update(self, u: float, dt: float) -> float:
        if self.tau <= 0.0:
            self.y = self.u = u
            return u
        a = math.exp(-dt / self.tau)
        b = 1.0 - self.tau / dt * (1.0 - a)  # weight of the input's change over the step
        self.y = a * self.y + (1.0 - a) * self.u + b * (u - self.u)
        self.u = u
        return self.y


def lab_results(rng: np.random.Generator, s: VirtualPlantSettings, hours: float,
                start_ns: int, moisture_at, shift: float, label: str) -> pd.DataFrame:
    """The day's lab results.

    ``moisture_at(t)`` gives the true outlet moisture [kg/kg] at ``t`` [s] from the start;
    ``shift`` [s] is the error of the stamped sample time (``lab_delay`` effect). The report
    delay is drawn so that the *stamped* delay stays within the settings' 20 to 90 min and
    the true one is at least 10 min.
    """
    rows = []
    end = hours * 3600.0
    t = rng.uniform(0.25, 1.0) * s.lab_interval_min
    i = 0
    while True:
        lo = max(s.lab_delay_min + shift, 600.0)
        hi = max(s.lab_delay_max + shift, lo + 60.0)
        delay = rng.uniform(lo, hi)
        if t + delay > end:
            break
        value = moisture_at(t) + rng.normal(0.0, s.noise_lab)
        rows.append({"log_time_ns": start_ns + int(round((t + delay) * 1e9)),
                     "sample_time_ns": start_ns + int(round((t + shift) * 1e9)),
                     "moisture_out": max(float(value), 0.0),
                     "sample_id": f"{label}-{i:03d}"})
        i += 1
        t += rng.uniform(s.lab_interval_min, s.lab_interval_max)
    return pd.DataFrame(rows, columns=["log_time_ns", "sample_time_ns", "moisture_out",
                                       "sample_id"])
