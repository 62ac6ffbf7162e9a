"""The plant's outlet-temperature loop: a PI controller, the flap drive and the air mixing.

The PID of the real plant moves ``flap_cmd`` to hold ``T_dryer_out`` at ``T_sp``; the flaps
mix hot combustion gas with ambient air into the tube's inlet air ``T_air_in``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from softsensor.model import humid_air as ha


def mixed_air(fraction: float, T_hot: float, Y_hot: float, T_amb: float,
              H_amb: float) -> tuple[float, float]:
    """Temperature [K] and humidity ratio [kg/kg] of hot gas mixed with ambient air.

    Adiabatic mixing by mass of dry gas (enthalpies of :mod:`softsensor.model.humid_air`):
    ``h = f h_hot + (1 - f) h_amb``, ``Y = f Y_hot + (1 - f) H_amb``.
    """
    h = fraction * ha.enthalpy(T_hot, Y_hot) + (1.0 - fraction) * ha.enthalpy(T_amb, H_amb)
    Y = fraction * Y_hot + (1.0 - fraction) * H_amb
    return float(ha.temperature(h, Y)), Y


def fraction_for_temperature(T_air_in: float, T_hot: float, Y_hot: float, T_amb: float,
                             H_amb: float) -> float:
    """Hot-gas fraction [-] that gives ``T_air_in`` (inverse of :func:`mixed_air`)."""
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if mixed_air(mid, T_hot, Y_hot, T_amb, H_amb)[0] < T_air_in:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass
class PIController:
    """Positional PI with conditional-integration anti-windup; output in % (0..100).

    ``u = kp * (e + integral / ti)``, ``e = T_sp - T_measured`` [K]; reverse acting is not
    needed: more hot gas raises the outlet temperature.
    """

    kp: float
    ti: float
    integral: float = 0.0
    out_min: float = 0.0
    out_max: float = 100.0

    def update(self, setpoint: float, measured: float, dt: float) -> float:
        e = setpoint - measured
        u = self.kp * (e + (self.integral + e * dt) / self.ti)
        if self.out_min < u < self.out_max or (u >= self.out_max and e < 0) or (
                u <= self.out_min and e > 0):
            self.integral += e * dt
        u = self.kp * (e + self.integral / self.ti)
        return min(max(u, self.out_min), self.out_max)

    def bumpless(self, output: float, setpoint: float, measured: float) -> None:
        """Set the integral so the current output is ``output`` (start-up without a kick)."""
        e = setpoint - measured
        self.integral = (output / self.kp - e) * self.ti


@dataclass
class FlapDrive:
    """Flap position [%] following the command through a first-order lag and a rate limit."""

    tau: float
    rate: float
    position: float = 50.0

    def update(self, command: float, dt: float) -> float:
        target = self.position + (command - self.position) * (1.0 - math.exp(-dt / self.tau))
        step = max(-self.rate * dt, min(self.rate * dt, target - self.position))
        self.position += step
        return self.position


class OutletLoop:
    """The whole outlet-temperature loop of the plant, as one object: the PI on the measured
    ``T_dryer_out`` moves the flap command [%], the :class:`FlapDrive` follows, and the flaps
    mix hot gas with ambient air into ``T_air_in`` [K] (:func:`mixed_air`).

    Started bumpless at the flap position that gives ``T_air0`` [K] with ambient ``T_amb``
    [K], ``H_amb`` [kg/kg] and set point ``T_sp0`` [K]. ``hot_gas`` is the plant config's
    ``[hot_gas]`` (temperature, humidity, fraction range), ``settings`` the
    ``[virtual_plant]`` (``kp``, ``ti``, ``actuator_tau``, ``actuator_rate``). The virtual
    plant and the design's prediction (:mod:`softsensor.apps.design`) step the same loop.
    """

    def __init__(self, hot_gas, settings, T_air0: float, T_amb: float, H_amb: float,
                 T_sp0: float) -> None:
        self.hot_gas = hg = hot_gas
        f0 = fraction_for_temperature(T_air0, hg.temperature, hg.humidity, T_amb, H_amb)
        pos0 = min(max((f0 - hg.fraction_min) / (hg.fraction_max - hg.fraction_min) * 100.0,
                       0.0), 100.0)
        self.pid = PIController(settings.kp, settings.ti)
        self.pid.bumpless(pos0, T_sp0, T_sp0)
        self.drive = FlapDrive(settings.actuator_tau, settings.actuator_rate, pos0)
        self.cmd = pos0  #: the flap command [%] in force

    def step(self, T_sp: float, measured: float, dt: float, T_amb: float,
             H_amb: float) -> float:
        """One control period ``dt`` [s]: the new command from the measured outlet
        temperature [K], the flaps moved, and the ``T_air_in`` [K] they give."""
        hg = self.hot_gas
        self.cmd = self.pid.update(T_sp, measured, dt)
        pos = self.drive.update(self.cmd, dt)
        frac = hg.fraction_min + (hg.fraction_max - hg.fraction_min) * pos / 100.0
        return mixed_air(frac, hg.temperature, hg.humidity, T_amb, H_amb)[0]

