"""Settings of the virtual plant: the ``[virtual_plant]`` table of the plant config.

Every field has a default so a plant config without the section works. Units SI, times in s.
"""

from __future__ import annotations

from dataclasses import dataclass

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of


@dataclass(frozen=True)
class VirtualPlantSettings:
    scan_period: float = num(10.0, gt=0, le=60)         # s, PLC scan
    control_period: float = num(20.0, gt=0, le=120)     # s, PID and plant step
    # PI controller: flap_cmd [%] from the T_dryer_out error [K]
    kp: float = num(0.25, gt=0)                          # %/K
    ti: float = num(120.0, gt=0)                         # s
    actuator_tau: float = num(20.0, gt=0)                # s, flap drive first-order lag
    actuator_rate: float = num(0.5, gt=0)                # %/s, flap drive rate limit
    # sensor noise, 1 sigma (CONTRACT section 6)
    noise_temperature: float = num(0.5, ge=0)            # K
    noise_flow: float = num(0.01, ge=0)                  # 1, flows' noise, relative
    noise_humidity: float = num(0.02, ge=0)              # 1, humidity's noise, relative
    noise_lab: float = num(0.003, ge=0)                  # kg/kg
    # laboratory schedule
    lab_interval_min: float = num(2.0 * 3600, gt=0)      # s
    lab_interval_max: float = num(4.0 * 3600, gt=0)      # s
    lab_delay_min: float = num(20.0 * 60, ge=0)          # s
    lab_delay_max: float = num(90.0 * 60, ge=0)          # s
    # disturbances
    m_fiber_min: float = num(4.8, gt=0)                  # kg/s, production levels
    m_fiber_max: float = num(7.0, gt=0)
    production_hold_min: float = num(2.0 * 3600, gt=0)  # s between production changes
    production_hold_max: float = num(8.0 * 3600, gt=0)
    setpoint_change_probability: float = num(0.3, ge=0, le=1)  # per production change
    ambient_amplitude_min: float = num(3.0, ge=0)        # K, daily cycle
    ambient_amplitude_max: float = num(8.0, ge=0)
    ambient_mean_min: float = num(268.0, gt=200)         # K
    ambient_mean_max: float = num(298.0, gt=200)

    def check(self) -> str | None:
        for lo, hi in (("lab_interval_min", "lab_interval_max"), ("lab_delay_min",
                       "lab_delay_max"), ("m_fiber_min", "m_fiber_max"),
                       ("production_hold_min", "production_hold_max"),
                       ("ambient_amplitude_min", "ambient_amplitude_max"),
                       ("ambient_mean_min", "ambient_mean_max")):
            if getattr(self, hi) < getattr(self, lo):
                return f"{hi} must be >= {lo} ({getattr(self, lo):g}), got {getattr(self, hi):g}"
        if self.control_period < self.scan_period and self.scan_period % self.control_period:
            return "control_period must divide scan_period"
        return None


def virtual_plant_settings(cfg: PlantConfig) -> VirtualPlantSettings:
    """The validated ``[virtual_plant]`` table of ``cfg`` (built once; defaults when
    absent)."""
    return section_of(cfg, "virtual_plant", VirtualPlantSettings)
