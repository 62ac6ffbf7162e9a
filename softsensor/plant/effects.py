"""Effects the virtual plant can hide in a recorded day (``softsensor simulate --effect``).

Each effect is one cause of CONTRACT section 5, with a ``--magnitude`` whose meaning, unit,
default and detectable range are fixed here (the diagnosis tests draw magnitudes from the
detectable range). Signs, timing and the affected sensor are drawn from the seed.

=================== ======================================================== ============ =========
effect              magnitude                                                default      detectable
=================== ======================================================== ============ =========
inlet_moisture      peak deviation of the inlet fibre moisture from nominal,  0.15 kg/kg   0.08-0.25
                    as a step plus a slow drift (clipped to 0.8-1.3 kg/kg)
sensor_bias         constant offset of one outlet temperature sensor          3.0 K        1.5-6.0
                    (``T_dryer_out`` or ``T_cyclone_out``, sign random)
lab_delay           error of the lab's stamped sample time (sign random)      45 min       30-60
fouling_drift       fractional loss of the tube's heat and mass transfer      0.3          0.2-0.5
                    (mult_h, mult_D) by the end of the record, linear in time
input_lag           time constant of a first-order lag of the ``T_air_in``    8 min        5-20
                    sensor
ambient_heat_loss   extra outside heat loss per 10 K of ambient below        0.5          0.3-1.0
                    283.15 K, as a fraction (model aux ``BETA_AMB`` = X/10 1/K)
unexplained         alternating chip batches: every 1.5 to 3 h the fibre's   0.25         0.15-0.4
                    drying rate switches between ``1 + X`` and ``1 - X``
                    times its value (matched plant: ``mult_D``; the
                    independent plant splits it between kinetics and
                    specific surface)
=================== ======================================================== ============ =========

The independent plant (:mod:`softsensor.plant.independent.effects`) gives every magnitude
the same meaning in its own physics.
"""

from __future__ import annotations

from dataclasses import dataclass

from softsensor.errors import ConfigError
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
