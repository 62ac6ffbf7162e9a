"""The outlet-temperature loop of the independent plant: PI, its tuning, the flap drive.

The PLC's PI runs in velocity (incremental) form,
``u_k = clip(u_(k-1) + Kc (e_k - e_(k-1)) + Kc dt / T_I e_k, 0, 100)`` (Astrom and Hagglund,
*Advanced PID Control*, 2006, sec. 3.5): clipping the output is its anti-windup, since no
integral state exists to wind up. A missing measurement holds the output. Tuning is the
SIMC rule for a first-order process with dead time (Skogestad 2003, *J. Process Control*
13:291, eqs. 3 and 4 with the closed-loop time constant ``tau_c = 2 theta`` for smooth
action on a noisy measurement), from the member's flap-to-outlet gain at the nominal point
and its lags, as the plant's commissioning engineer would tune it.

The PI sees the measured outlet temperature through the PLC's input filter, a first-order
lag of :data:`PV_FILTER` seconds (as analog inputs of process PLCs are set up to keep 0.5 K of
sensor noise off the flaps); the tuning counts half of it as dead time.

The flap drive follows the command through a first-order lag and a rate limit
(``actuator_tau``, ``actuator_rate`` of the ``[virtual_plant]`` settings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PV_FILTER = 30.0  # s, first-order filter of the measured outlet temperature in the PLC

@dataclass
class VelocityPI:
    """Incremental PI on ``e = setpoint - measured`` [K]; output in % (0..100)."""

    kc: float           # %/K
    ti: float           # s
    output: float = 50.0
    last_error: float | None = None

    def update(self, setpoint: float, measured: float, dt: float) -> float:
        if math.isnan(measured):  # sensor not read this scan: hold
            return self.output
        e = setpoint - measured
        de = 0.0 if self.last_error is None else e - self.last_error
        self.output = min(max(self.output + self.kc * (de + dt / self.ti * e), 0.0), 100.0)
        self.last_error = e
        return self.output


@dataclass
class FlapDrive:
    """Flap position [%]: first-order lag ``tau`` [s] and rate limit ``rate`` [%/s]."""

    tau: float
    rate: float
    position: float

    def update(self, command: float, dt: float) -> float:
        want = (command - self.position) * -math.expm1(-dt / self.tau)
        limit = self.rate * dt
        self.position += min(max(want, -limit), limit)
        return self.position


def simc_tuning(gain: float, tau: float, theta: float) -> tuple[float, float]:
    """SIMC PI settings ``(Kc [%/K], T_I [s])`` for a process of ``gain`` [K/%], lag
    ``tau`` [s] and dead time ``theta`` [s], with ``tau_c = 2 theta``."""
    tau_c = 2.0 * theta
    kc = tau / (gain * (tau_c + theta))
    ti = min(tau, 4.0 * (tau_c + theta))
    return kc, ti
