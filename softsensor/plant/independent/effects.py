"""How each cause of CONTRACT section 5 is hidden in an independent-plant day.

Magnitudes mean what :data:`softsensor.plant.effects.EFFECTS` says (same unit, default and
valid range as the matched plant); here they act on this plant's own physics:

=================== =========================================================================
inlet_moisture      the true inlet moisture gets a deviation of at most the magnitude: a step
                    of 0.65 X (raised-cosine over 10 min, at 20 to 50 % of the record, sign
                    drawn) plus a slow sine of 0.35 X (period 0.6 to 1.4 records), on top of
                    the day's natural wander; clipped to 0.8..1.3 kg/kg
sensor_bias         a constant offset of X K on ``T_dryer_out`` or ``T_cyclone_out`` (drawn,
                    sign drawn); the loop acts on the biased reading
lab_delay           the lab stamps its sample times X min late or early (sign drawn)
fouling_drift       the tube's and duct's gas-fibre heat and mass transfer coefficients fall
                    linearly in time to ``1 - X`` at the end of the record
input_lag           the ``T_air_in`` reading passes an extra first-order lag of X min (after
                    its thermocouple's own lag)
ambient_heat_loss   every outside coefficient (tube, duct, cyclone shells; convection and
                    radiation) grows by the fraction X per 10 K of ambient below 283.15 K
unexplained         alternating chip batches: every 1.5 to 3 h the fibre's drying rate
                    switches between ``1 + X`` and ``1 - X`` times its own (first level
                    drawn), half of it (``sqrt(1 +- X)``) through the kinetic multiplier and
                    half through the open specific surface in tube and cyclone
=================== =========================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.plant.effects import EFFECTS

T_COLD = 283.15  # K, below it the ambient_heat_loss effect grows


@dataclass
class Injection:
    """What one effect changes in the day (neutral values when ``effect`` is None)."""

    moisture_dev: np.ndarray          # kg/kg added to the inlet moisture
    xfer: np.ndarray                  # tube gas-fibre transfer multiplier [-]
    batch: np.ndarray                 # drying-rate multiplier of the chip batch [-]
    loss_per_10K: float = 0.0         # ambient_heat_loss magnitude [fraction per 10 K]
    input_lag: float = 0.0            # s, extra lag on the T_air_in reading
    bias: dict[str, float] = field(default_factory=lambda: {"T_dryer_out": 0.0,
                                                            "T_cyclone_out": 0.0})
    lab_shift: float = 0.0            # s, error of the stamped lab sample time
    info: dict[str, Any] = field(default_factory=dict)

    def loss_mult(self, T_amb: float) -> float:
        """Outside-loss multiplier [-] at ambient ``T_amb`` [K]."""
        return 1.0 + self.loss_per_10K * max(0.0, T_COLD - T_amb) / 10.0


def inject(effect: str | None, magnitude: float, rng: np.random.Generator, t: np.ndarray,
           seed: int) -> Injection:
    """Draw the timing, sign and channel of ``effect`` from ``rng`` for step times ``t`` [s]."""
    n = len(t)
    inj = Injection(moisture_dev=np.zeros(n), xfer=np.ones(n), batch=np.ones(n))
    inj.info = {"effect": effect or "none", "magnitude": magnitude,
                "unit": EFFECTS[effect].unit if effect else "", "seed": seed, "channel": None}
    span = max(float(t[-1]), 1.0)
    if effect == "inlet_moisture":
        sign = float(rng.choice([-1.0, 1.0]))
        t_step = rng.uniform(0.2, 0.5) * span
        x = np.clip((t - t_step) / 600.0, 0.0, 1.0)
        step = sign * 0.65 * magnitude * (0.5 - 0.5 * np.cos(np.pi * x))
        drift = 0.35 * magnitude * np.sin(2 * np.pi * t / (rng.uniform(0.6, 1.4) * span)
                                          + rng.uniform(0.0, 2 * np.pi))
        inj.moisture_dev = step + drift
        inj.info.update(sign=sign, step_time_s=round(float(t_step), 1))
    elif effect == "sensor_bias":
        channel = str(rng.choice(["T_dryer_out", "T_cyclone_out"]))
        sign = float(rng.choice([-1.0, 1.0]))
        inj.bias[channel] = sign * magnitude
        inj.info.update(channel=channel, sign=sign)
    elif effect == "lab_delay":
        sign = float(rng.choice([-1.0, 1.0]))
        inj.lab_shift = sign * magnitude * 60.0
        inj.info.update(sign=sign)
    elif effect == "fouling_drift":
        inj.xfer = 1.0 - magnitude * t / span
    elif effect == "input_lag":
        inj.input_lag = magnitude * 60.0
    elif effect == "ambient_heat_loss":
        inj.loss_per_10K = magnitude
    elif effect == "unexplained":
        sign = float(rng.choice([-1.0, 1.0]))
        edges = [0.0]
        while edges[-1] < span:
            edges.append(edges[-1] + rng.uniform(1.5, 3.0) * 3600.0)
        block = np.searchsorted(np.array(edges), t, side="right") - 1
        inj.batch = 1.0 + magnitude * sign * np.where(block % 2 == 0, 1.0, -1.0)
        inj.info.update(sign=sign, switch_times_s=[round(e, 1) for e in edges[1:-1]])
    return inj
