"""Advisor settings: the optional ``[advisor]`` table of the plant config.

One frozen dataclass, validated on load by :func:`softsensor.configfile.build_section`
(unknown keys rejected, ranges checked, errors naming ``advisor.<key>``). Every field has a
default, so a config without the table works. Why each default is what it is:
:doc:`/explanation/set-point-advisor`.

Example ``config/dryer1.toml`` fragment::

    [advisor]
    moisture_target = 0.10      # kg/kg dry basis
    moisture_max = 0.16
    confidence = 0.95
"""

from __future__ import annotations

from dataclasses import dataclass

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of


@dataclass(frozen=True)
class AdvisorSettings:
    """Tuning of the set-point advisor (``[advisor]`` in the plant config). SI units.

    Attributes
    ----------
    moisture_target : float
        Outlet moisture the advised set point aims at (CONTRACT section 6: about 0.10).
        [kg/kg]
    moisture_max : float
        Upper limit of the specification (CONTRACT section 6: acceptable up to 0.16). [kg/kg]
    confidence : float
        Probability with which the outlet moisture at the advised set point stays at or
        below ``moisture_max`` (one-sided). [-]
    envelope_sd : float
        The operating envelope the history covers: each feature of the parameters'
        ``[model_error]`` (window means over the calibration history) within its history
        mean plus or minus this many history standard deviations. [-]
    production_change : float
        Relative change of the dry-fibre flow's window means within ``steady_window`` that
        counts as a production change (no advice while the plant moves). [-]
    setpoint_change : float
        Change of ``T_sp`` within ``steady_window`` that counts as an operator's move. [K]
    steady_window : float
        How far back the production and set-point changes are looked for. [s]
    max_step : float
        Largest set-point move advised at once. [K]
    settle_fraction : float
        The plant has settled at the advised set point when the model's outlet moisture is
        within this fraction of the move from its new steady value. [-]
    settle_horizon : float
        Longest settling time simulated; a slower settle is reported as longer than it. [s]
    enabled : bool
        The daemon advises at every tick and publishes on ``softsensor/<unit>/advice``.
    identify : str
        The daemon's parameter covariance: the JSON of ``softsensor identify --json`` (a path;
        relative to the working directory). Required when ``enabled``.
    """

    moisture_target: float = num(0.10, gt=0, lt=1)
    moisture_max: float = num(0.16, gt=0, lt=1)
    confidence: float = num(0.95, gt=0.5, lt=1)
    envelope_sd: float = num(3.0, gt=0)
    production_change: float = num(0.03, gt=0)
    setpoint_change: float = num(0.5, gt=0)
    steady_window: float = num(3600.0, gt=0)
    max_step: float = num(10.0, gt=0)
    settle_fraction: float = num(0.1, gt=0, lt=1)
    settle_horizon: float = num(6 * 3600.0, gt=0)
    enabled: bool = False
    identify: str = ""

    def check(self) -> str | None:
        if self.enabled and not self.identify:
            return "identify must name the JSON of softsensor identify when enabled"
        if self.moisture_max <= self.moisture_target:
            return (f"moisture_max ({self.moisture_max:g}) must be above moisture_target "
                    f"({self.moisture_target:g})")
        return None


def advisor_settings(cfg: PlantConfig) -> AdvisorSettings:
    """The validated ``[advisor]`` table of ``cfg`` (built once; defaults when absent)."""
    return section_of(cfg, "advisor", AdvisorSettings)
