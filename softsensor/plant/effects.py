"""Effects the virtual plant can hide in a recorded day (``softsensor simulate --effect``).

Each effect is one cause of CONTRACT section 5, with a ``--magnitude`` whose meaning, unit,
default and detectable range are fixed here (the diagnosis tests draw magnitudes from the
detectable range). Signs, timing and the affected sensor are drawn from the seed.

================= ====================================================== ========== ==========
effect            magnitude                                              default    detectable
================= ====================================================== ========== ==========
inlet_moisture    peak deviation of the inlet fibre moisture from        0.15 kg/kg 0.08-0.25
                  nominal, as a step plus a slow drift (clipped to
                  0.8-1.3 kg/kg)
sensor_bias       constant offset of one outlet temperature sensor       3.0 K      1.5-6.0
                  (``T_dryer_out`` or ``T_cyclone_out``, sign random)
lab_delay         error of the lab's stamped sample time (sign random)   45 min     30-60
fouling_drift     fractional loss of the tube's heat and mass transfer   0.3        0.2-0.5
                  (mult_h, mult_D) by the end of the record, linear in
                  time
input_lag         time constant of a first-order lag of the ``T_air_in`` 8 min      5-20
                  sensor
ambient_heat_loss extra outside heat loss per 10 K of ambient below      0.5        0.3-1.0
                  283.15 K, as a fraction (model aux ``BETA_AMB`` = X/10
                  1/K)
unexplained       alternating chip batches: every 1.5 to 3 h the fibre's 0.25       0.15-0.4
                  drying rate switches between ``1 + X`` and ``1 - X``
                  times its value (matched plant: ``mult_D``; the
                  independent plant splits it between kinetics and
                  specific surface)
================= ====================================================== ========== ==========

The independent plant (:mod:`softsensor.plant.independent.effects`) gives every magnitude
the same meaning in its own physics.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from softsensor.errors import ConfigError
from softsensor.plantconfig import PARAMETER_NAMES
from softsensor.signals import INJECTABLE_EFFECTS


@dataclass(frozen=True)
class EffectSpec:
    name: str
    unit: str
    default: float
    detectable: tuple[float, float]
    valid: tuple[float, float]  # magnitudes outside this are refused
    meaning: str


EFFECTS: dict[str, EffectSpec] = {
    "inlet_moisture": EffectSpec("inlet_moisture", "kg/kg", 0.15, (0.08, 0.25), (0.0, 0.5),
                                 "peak deviation of the inlet fibre moisture from nominal"),
    "sensor_bias": EffectSpec("sensor_bias", "K", 3.0, (1.5, 6.0), (0.0, 30.0),
                              "constant offset of one outlet temperature sensor"),
    "lab_delay": EffectSpec("lab_delay", "min", 45.0, (30.0, 60.0), (0.0, 75.0),
                            "error of the lab's stamped sample time"),
    "fouling_drift": EffectSpec("fouling_drift", "fraction", 0.3, (0.2, 0.5), (0.0, 0.9),
                                "loss of tube heat and mass transfer by the end of the record"),
    "input_lag": EffectSpec("input_lag", "min", 8.0, (5.0, 20.0), (0.0, 120.0),
                            "time constant of a first-order lag of the T_air_in sensor"),
    "ambient_heat_loss": EffectSpec("ambient_heat_loss", "fraction per 10 K", 0.5, (0.3, 1.0),
                                    (0.0, 5.0), "extra outside heat loss per 10 K of cold"),
    "unexplained": EffectSpec("unexplained", "fraction", 0.25, (0.15, 0.4), (0.0, 0.6),
                              "alternating chip batches: kinetic rate switches by +- X"),
}
assert set(EFFECTS) == set(INJECTABLE_EFFECTS)


def resolve_effect(effect: str | None, magnitude: float | None) -> tuple[str | None, float]:
    """Validate ``--effect``/``--magnitude``; returns the effect and its magnitude (default
    when omitted). Raises ConfigError naming the bad value."""
    if effect is None or effect == "none":
        if magnitude is not None:
            raise ConfigError("--magnitude given without --effect")
        return None, 0.0
    if effect not in EFFECTS:
        raise ConfigError(f"unknown effect {effect!r} (known: {', '.join(EFFECTS)})")
    spec = EFFECTS[effect]
    if magnitude is None:
        return effect, spec.default
    lo, hi = spec.valid
    if not lo <= magnitude <= hi:
        raise ConfigError(f"--magnitude {magnitude:g} {spec.unit} is outside the valid range "
                          f"{lo:g}..{hi:g} of effect {effect}")
    return effect, float(magnitude)


# ----------------------------------------------------------------------------------------------
# How each effect is injected into a matched-plant day (softsensor.plant.simulator)

_MULT_D = PARAMETER_NAMES.index("mult_D")
_MULT_H = PARAMETER_NAMES.index("mult_h")


@dataclass
class Injection:
    """What the hidden effect changes in a matched-plant day; an effect's function edits it.

    ``t`` are the control-step times [s from the start], ``theta`` the true parameters per
    step (n, 7), ``moisture_in`` the true inlet moisture per step [kg/kg]; ``bias`` the offset
    of each outlet temperature sensor [K]; ``beta_amb`` the model aux ``BETA_AMB`` [1/K];
    ``lag_tau`` the ``T_air_in`` sensor's time constant [s] (0: none); ``lab_shift`` the error
    of the stamped lab sample time [s]; ``info`` what ``/truth/effect`` records.
    """

    t: np.ndarray
    theta: np.ndarray
    moisture_in: np.ndarray
    nominal_moisture_in: float
    info: dict[str, Any]
    bias: dict[str, float] = field(
        default_factory=lambda: {"T_dryer_out": 0.0, "T_cyclone_out": 0.0})
    beta_amb: float = 0.0
    lag_tau: float = 0.0
    lab_shift: float = 0.0


def _inlet_moisture(inj: Injection, rng: np.random.Generator, x: float) -> None:
    # imported here: the scenario module imports the model, and this module stays light for
    # the command line's list of effects
    from softsensor.plant.scenario import inlet_moisture_trajectory

    inj.moisture_in = inlet_moisture_trajectory(rng, inj.t, inj.nominal_moisture_in, x)


def _sensor_bias(inj: Injection, rng: np.random.Generator, x: float) -> None:
    channel = str(rng.choice(["T_dryer_out", "T_cyclone_out"]))
    sign = float(rng.choice([-1.0, 1.0]))
    inj.bias[channel] = sign * x
    inj.info.update(channel=channel, sign=sign)


def _fouling_drift(inj: Injection, rng: np.random.Generator, x: float) -> None:
    frac = inj.t / inj.t[-1]
    inj.theta[:, _MULT_D] *= 1.0 - x * frac
    inj.theta[:, _MULT_H] *= 1.0 - x * frac


def _input_lag(inj: Injection, rng: np.random.Generator, x: float) -> None:
    inj.lag_tau = x * 60.0


def _ambient_heat_loss(inj: Injection, rng: np.random.Generator, x: float) -> None:
    inj.beta_amb = x / 10.0


def _lab_delay(inj: Injection, rng: np.random.Generator, x: float) -> None:
    inj.lab_shift = float(rng.choice([-1.0, 1.0])) * x * 60.0
    inj.info.update(sign=float(np.sign(inj.lab_shift)))


def _unexplained(inj: Injection, rng: np.random.Generator, x: float) -> None:
    # alternating chip batches: mult_D switches between 1 +- x every 1.5 to 3 h
    sign = float(rng.choice([-1.0, 1.0]))
    edges = [0.0]
    while edges[-1] < inj.t[-1]:
        edges.append(edges[-1] + rng.uniform(1.5, 3.0) * 3600.0)
    block = np.searchsorted(np.array(edges), inj.t, side="right") - 1
    inj.theta[:, _MULT_D] *= 1.0 + x * sign * np.where(block % 2 == 0, 1.0, -1.0)
    inj.info.update(sign=sign)


#: Effect name -> ``inject(injection, rng, magnitude)``, drawing signs and timing from ``rng``.
INJECT: dict[str, Callable[[Injection, np.random.Generator, float], None]] = {
    "inlet_moisture": _inlet_moisture,
    "sensor_bias": _sensor_bias,
    "lab_delay": _lab_delay,
    "fouling_drift": _fouling_drift,
    "input_lag": _input_lag,
    "ambient_heat_loss": _ambient_heat_loss,
    "unexplained": _unexplained,
}
assert set(INJECT) == set(EFFECTS)
