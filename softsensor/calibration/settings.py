"""Calibration settings: the optional ``[calibration]`` table of the plant config.

One frozen dataclass, validated on load (:func:`softsensor.configfile.build_section`); every
field has a default and the ``calibrate`` verb's options override them. What each choice does
is in :mod:`softsensor.calibration.objective`.

Example ``config/dryer1.toml`` fragment::

    [calibration]
    cost = "likelihood"        # or "eq4", the paper's
    prior_sigma = 1.0          # sd of ln(theta) around the config's values
    inlet = "estimated"        # the unmeasured inlet moisture, fitted as a slow trajectory
"""

from __future__ import annotations

from dataclasses import dataclass

from softsensor.configfile import build_section, num
from softsensor.plantconfig import PlantConfig

#: The Optuna study a calibration writes to and resumes from in its storage.
DEFAULT_STUDY_NAME = "softsensor-calibration"
#: Trials of a calibration unless asked otherwise, as the paper's study (``calibrate`` and
#: ``diagnose --calibrate-on`` alike).
DEFAULT_TRIALS = 200

#: Cost functions the calibration offers (:mod:`softsensor.calibration.objective`).
COSTS: tuple[str, ...] = ("eq4", "likelihood")
#: How the unmeasured inlet moisture enters the fit.
INLET_MODES: tuple[str, ...] = ("nominal", "estimated")


@dataclass(frozen=True)
class CalibrationSettings:
    """Tuning of the calibration (``[calibration]`` in the plant config).

    Attributes
    ----------
    cost : str
        ``"likelihood"`` (default): the Gaussian likelihood with each channel's noise
        estimated from the data; ``"eq4"``: the paper's weighted sum of RMSEs (eq. 4, weights
        from ``[cost]``), whose number is reported beside either way. Under eq. 4 a 3 K
        temperature error costs less than 0.002 kg/kg of moisture, and with the inlet
        trajectory fitted to the labs it buys lab moisture below the lab's noise with the
        temperatures: on the matched plant (3 x 24 h, 60 trials) eq. 4 scored its result
        0.0139 on the calibration windows against 0.0293 at the true parameters (labs 0.0005
        against the noise's 0.0047 kg/kg, the dryer outlet 0.99 K against 0.08 K), so no
        search could have found the truth; held out, 1.81 times the truth's eq. 4. The
        likelihood weighs each channel by its own noise; with the stronger polish its result
        scored below the truth's likelihood on the windows and 1.08 times the truth's eq. 4
        held out. On an independent plant (seed 5151, 7 x 48 h, 200 trials) its held-out
        RMSE was 0.25/0.34 K and 0.0075 kg/kg against eq. 4's 1.30/1.00 K and 0.0080, the
        sensor's pooled RMSE the same (0.0115 against 0.0114 kg/kg).
    prior : bool
        Fit the maximum a posteriori: a Gaussian prior on ``ln(theta)`` centred on the
        config's values (the Table 1 ranges are bounds, not knowledge). False: the paper's
        plain fit within the bounds.
    prior_sigma : float
        Standard deviation of that prior in ``ln(theta)`` [-] (1.0: a factor e).
    inlet : str
        ``"estimated"``: the inlet moisture, which no instrument measures, is fitted with the
        parameters as a slow trajectory per day (a nuisance); ``"nominal"``: held at
        ``nominal.moisture_in`` (the paper's model).
    inlet_knot_hours : float
        Spacing of the trajectory's knots (piecewise linear) [h].
    inlet_level_std : float
        Prior standard deviation of a day's inlet moisture about the nominal [kg/kg].
    inlet_walk : float
        Random-walk intensity of the trajectory between knots [kg/kg / sqrt(h)].
    holdout_fraction : float
        Share of each calibration window, at its end, held out to validate the result when no
        other day is given (0: validate on the calibration data itself).
    bound_margin : float
        A parameter within this fraction of a bound (``value <= low (1 + m)`` or
        ``value >= high / (1 + m)``) is flagged as at its bound.
    polish_passes, polish_evaluations : int
        The local polish of the study's best point (:func:`~softsensor.calibration.refine.
        refine`): at most this many re-weighted Gauss-Newton passes of at most this many
        evaluations each (why these: the documentation's calibration results).
    temperature_target, moisture_target : float
        What fitting the dryer means on held-out data: both outlet temperatures' RMSE within
        ``temperature_target`` [K] and the lab moisture's within ``moisture_target``
        [kg/kg]; the calibration's front says whether any choice of the multipliers gets
        there (:mod:`softsensor.calibration.trade_off`).
    search_wall_substeps : int
        Crank-Nicolson substeps of the wall per window in the TPE search; the search's best
        point is then polished, validated and reported with ``solver.wall_substeps``. The wall
        moves by a fraction of a kelvin per window, so one substep changes the outputs of the
        demo day by less than 0.01 K and 2e-5 kg/kg against four, and halves the search's time
        (``benchmarks/calibrate.py``). 0: ``solver.wall_substeps``.
    """

    cost: str = "likelihood"
    prior: bool = True
    prior_sigma: float = num(1.0, gt=0, le=20)
    inlet: str = "estimated"
    inlet_knot_hours: float = num(4.0, gt=0, le=240)
    inlet_level_std: float = num(0.1, gt=0, lt=2)
    inlet_walk: float = num(0.015, ge=0, lt=2)
    holdout_fraction: float = num(0.25, ge=0, lt=0.9)
    bound_margin: float = num(0.02, gt=0, lt=1)
    search_wall_substeps: int = num(1, ge=0, le=1000)
    polish_passes: int = num(4, ge=1, le=20)
    polish_evaluations: int = num(15, ge=1, le=200)
    temperature_target: float = num(1.0, gt=0, le=100)
    moisture_target: float = num(0.006, gt=0, le=1)

    def check(self) -> str | None:
        if self.cost not in COSTS:
            return f"cost must be one of {', '.join(COSTS)}, got {self.cost!r}"
        if self.inlet not in INLET_MODES:
            return f"inlet must be one of {', '.join(INLET_MODES)}, got {self.inlet!r}"
        return None


def calibration_settings(cfg: PlantConfig) -> CalibrationSettings:
    """The validated ``[calibration]`` table of ``cfg`` (defaults when absent)."""
    return build_section(CalibrationSettings, cfg.extra.get("calibration", {}), "calibration",
                         cfg.source)


__all__ = ["COSTS", "DEFAULT_STUDY_NAME", "DEFAULT_TRIALS", "INLET_MODES", "CalibrationSettings",
           "calibration_settings"]
