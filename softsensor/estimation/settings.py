"""Estimator settings: the optional ``[estimator]`` table of the plant config.

One frozen dataclass, validated on load by :func:`softsensor.configfile.build_section` (unknown
keys rejected, ranges checked, errors naming ``estimator.<key>``). Every field has a default, so
a config without the table works. Random-walk intensities are given per square root of an hour
(a physical rate a process engineer can judge); the filter scales them to its window:
``q_window = q_hour * sqrt(window / 3600 s)``.

Example ``config/dryer1.toml`` fragment::

    [estimator]
    kind = "ukf"
    moisture_in_walk = 0.05        # kg/kg per sqrt(h)
    history_hours = 8.0
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of

#: Estimator kinds the service can build (see :func:`softsensor.service.estimators.make_estimator`).
ESTIMATOR_KINDS: tuple[str, ...] = ("ukf", "openloop")


@dataclass(frozen=True)
class EstimatorSettings:
    """Tuning of the estimators (``[estimator]`` in the plant config). SI units.

    Attributes
    ----------
    kind : str
        Estimator the service runs: ``"ukf"`` (default) or ``"openloop"``.
    moisture_in_std0 : float
        Prior standard deviation of the inlet fibre moisture at start-up. [kg/kg]
    moisture_in_std_floor : float
        Smallest prior standard deviation of the inlet moisture at start-up when the
        parameters carry a ``[model_error]`` (which gives the history's spread of the days'
        inlet-moisture levels). [kg/kg]
    moisture_in_walk : float
        Random-walk intensity of the inlet moisture. [kg/kg / sqrt(h)]
    moisture_in_tau_h : float
        Time over which the inlet moisture's estimate returns to its reference (the nominal,
        or the history's typical level with a ``[model_error]``) when nothing says otherwise
        (a mean-reverting walk, stationary standard deviation ``walk sqrt(tau / 2)``):
        evidence the model cannot split between the inlet moisture and its own error does not
        pile up in the inlet moisture for ever. [h]
    moisture_in_adapt : float
        Temperature innovations more than this many standard deviations along what an inlet
        moisture change would do widen its prior (a step; covariance matching, see
        :func:`softsensor.estimation.ukf_step._match_covariance`). [-]
    moisture_in_min, moisture_in_max : float
        Range the model is evaluated in; sigma points outside it are clipped. [kg/kg]
    moisture_out_bias_adapt : float
        A lab result more than this many standard deviations from the estimate (given the
        tick's temperatures) widens the bias prior so its innovation becomes one standard
        deviation (covariance matching, as for the inlet moisture). [-]
    offset_adapt : float
        The same for one outlet temperature channel's own offset (a thermometer that steps). [-]
    T_offset_std, T_channel_std : float
        Default stationary standard deviations of the outlet temperatures' common offset and
        of each channel's own offset, used when the parameters carry no ``[discrepancy]``
        from a calibration (with a history's ``[model_error]`` the channels' come from its day
        spread). [K]
    T_offset_tau_h, T_channel_tau_h : float
        Their default correlation times [h]. The calibration sets the common offset's (the
        model's energy balance drifts with the conditions); a channel's own offset keeps the
        long default (a thermometer that reads off stays off).
    inlet_gain_std : float or None
        Prior standard deviation of the relative error of the model's outlet-moisture
        response to the inlet moisture (:mod:`~softsensor.estimation.state_space`,
        ``inlet_gain``): 1 says the plant's response may be anywhere from none to twice the
        model's. Default (None): 1 when the parameters carry a history's ``[model_error]``
        (the history says how the model is not the plant), else the gain is held at zero
        (a model nobody has compared with its plant is taken as it is). [-]
    inlet_gain_walk : float
        Its random-walk intensity (the fibre's drying behaviour changes slowly). [-/sqrt(h)]
    moisture_out_bias_std : float
        Default stationary standard deviation of the outlet-moisture bias. [kg/kg]
    moisture_out_bias_tau_h : float
        Its correlation time. [h]
    T_std_floor, moisture_std_floor : float
        Floors on the calibration's numbers (a validation day can be luckier than the next).
        [K, kg/kg]
    adapt_ticks : int
        Memory of the innovation-based noise adaptation, in ticks
        (:class:`~softsensor.estimation.state_space.AdaptiveNoise`). [-]
    adapt_limit : float
        Largest inflation of an error state's process noise. [-]
    inlet_margin : float
        Width of the soft clip at each end of ``[moisture_in_min, moisture_in_max]``. [kg/kg]
    guard_sigma : float
        The heat input's offset beyond this many of its prior standard deviations says the
        model has lost the plant (the lab-anchored fallback is published); the outlet-moisture
        bias beyond it, or the two outlet channels' offsets differing by more than it in units
        of their difference, degrade the health only
        (:mod:`softsensor.estimation.publication`). [-]
    fallback_drift : float
        How fast the lab-anchored fallback's band widens after the last lab result.
        [kg/kg / sqrt(h)]
    temperature_sensor_std : float
        Noise of one temperature scan; a window mean of ``n`` good scans has
        ``temperature_sensor_std / sqrt(n)``. [K]
    temperature_model_std : float
        Model error of a window's outlet temperatures, added in quadrature. [K]
    transient_fraction : float
        Share of an inlet-air-temperature move inside a window (the spread of its bin means,
        times the model's outlet-temperature gain) taken as extra noise of that window's
        outlet temperatures (:func:`softsensor.estimation.ukf_step.transient_variance`):
        the model's mean-input step cannot follow a lagging thermometer, a surge or a
        production move, and the filter should not read that miss as inlet moisture. 0
        turns it off. 0.2 is the largest share that keeps the matched plant's band within its
        99.5 % bound; 0.5 was as good or better on the independent plant's event days (the
        figures, and how they were measured: ``docs/results/accuracy.md``). [-]
    lab_std : float
        Noise of one lab moisture result (CONTRACT section 6). [kg/kg]
    moisture_out_jitter_std : float
        Short-term variation of the outlet moisture around its window mean: the outlet loop
        moves the air temperature every few seconds, and a 600 s window cannot follow it
        (0.004 kg/kg on the virtual plant). A grab sample sees it, so it adds to ``lab_std``;
        and it is part of the uncertainty of the outlet moisture *at* the tick, so it adds to
        the reported ``moisture_out_std`` (``moisture_out_window_std`` leaves it out). [kg/kg]
    moisture_out_min, moisture_out_max : float
        Range the published outlet moisture is held in (``clipped`` says when it was); lab
        results are held to the one lab-result contract of :mod:`softsensor.messages`
        (``MOISTURE_RANGE``), not to this. [kg/kg]
    lab_envelope_min, lab_envelope_max : float
        The plant lab's operating envelope: a result outside it is refused and counted
        whatever came before (a typo such as 0.999 kg/kg lies inside the 0..2 contract but no
        outlet of this dryer is that wet); its ``sample_id`` is not remembered, so the
        corrected result may follow under the same id. [kg/kg dry basis]
    lab_gate : float
        A lab result further than this many standard deviations of its innovation from the
        estimate at its sample time is rejected as an outlier; the second in a row on the
        same side is taken only when it agrees with what the temperatures say (within
        ``lab_gate`` standard deviations once the model's plausible outlet-moisture bias,
        the bias state's prior spread, is added). [-]
    history_hours : float
        Estimator history kept to apply late lab results; older samples are skipped. [h]
    consistency_ticks : int
        Ticks in the chi-square consistency window of the innovations. [-]
    consistency_alpha : float
        False-alarm probability of that test per window. [-]
    sigma_alpha, sigma_beta, sigma_kappa : float
        Van der Merwe scaled sigma points (filterpy ``MerweScaledSigmaPoints``).
    peer_blend : bool
        Weigh the physics against the plant's simple peers (the last lab result held, the
        history's lab regression) by their recent lab likelihood and publish the weighted
        estimate (:mod:`softsensor.estimation.peer_blend`); false publishes the physics alone.
    peer_prior_physics : float
        Prior weight of the physics: where the weights return when the labs say nothing. [-]
    peer_prior_hold : float or None
        Prior weight of the held lab; the regression takes the rest (without a regression the
        hold takes all the physics leaves). Default (None): the two peers share the rest
        equally. A calibration from history learns the prior weights out of fold
        (:mod:`softsensor.calibration.sensor_tuning`, PARAMS.toml's ``[sensor]``). [-]
    peer_evidence : float
        Tempering of each lab result's evidence on the weights: its log likelihood is
        multiplied by this (0: the weights stay at the prior, a fixed stacking of the sources;
        1: dynamic model averaging's full evidence). [-]
    peer_forgetting : float
        How much of the weights' log evidence each lab result keeps of what came before
        (dynamic model averaging's forgetting factor; 0.85 keeps a result's evidence at half
        after four more). [-]
    band_conformal : bool
        Scale the published band by the adaptive conformal scale updated at each lab result
        towards 95 % coverage (:mod:`softsensor.estimation.peer_blend`). [-]
    band_step : float
        Step of the band's log scale per lab result (a miss widens it by
        ``exp(0.95 band_step)``, a hit narrows it by ``exp(-0.05 band_step)``). [-]
    band_scale_min, band_scale_max : float
        Bounds of that scale. [-]
    openloop_moisture_in_std, openloop_moisture_out_std : float
        Fixed standard deviations the open-loop estimator reports (a prior, not an estimate:
        the open-loop model has no feedback to learn its error from). [kg/kg]
    """

    kind: str = "ukf"
    moisture_in_std0: float = num(0.15, gt=0, lt=2)
    moisture_in_std_floor: float = num(0.03, gt=0, lt=2)
    moisture_in_walk: float = num(0.008, ge=0, lt=2)
    moisture_in_tau_h: float = num(48.0, gt=0, le=1e6)
    moisture_in_adapt: float = num(3.0, gt=0)
    moisture_in_min: float = num(0.3, gt=0, lt=5)
    moisture_in_max: float = num(2.5, gt=0, lt=5)
    moisture_out_bias_adapt: float = num(5.0, gt=0)
    offset_adapt: float = num(3.0, gt=0)
    T_offset_std: float = num(1.0, gt=0, lt=50)
    T_channel_std: float = num(0.5, gt=0, lt=50)
    T_offset_tau_h: float = num(6.0, gt=0, le=240)
    T_channel_tau_h: float = num(24.0, gt=0, le=240)
    inlet_gain_std: float | None = num(None, gt=0, le=10)
    inlet_gain_walk: float = num(0.05, ge=0, le=10)
    moisture_out_bias_std: float = num(0.01, gt=0, lt=1)
    moisture_out_bias_tau_h: float = num(24.0, gt=0, le=2400)
    T_std_floor: float = num(0.2, ge=0, lt=50)
    moisture_std_floor: float = num(0.003, ge=0, lt=1)
    adapt_ticks: int = num(12, ge=1, le=10000)
    adapt_limit: float = num(25.0, ge=1)
    inlet_margin: float = num(0.1, gt=0, lt=1)
    guard_sigma: float = num(4.0, gt=0)
    fallback_drift: float = num(0.01, ge=0, lt=1)
    temperature_sensor_std: float = num(0.5, gt=0, lt=20)
    temperature_model_std: float = num(0.02, ge=0, lt=20)
    transient_fraction: float = num(0.2, ge=0, le=10)
    lab_std: float = num(0.003, gt=0, lt=1)
    moisture_out_jitter_std: float = num(0.004, ge=0, lt=1)
    moisture_out_min: float = num(0.0, ge=0, lt=5)
    moisture_out_max: float = num(0.6, gt=0, le=5)
    lab_envelope_min: float = num(0.02, ge=0, lt=2)
    lab_envelope_max: float = num(0.40, gt=0, le=2)
    lab_gate: float = num(6.0, gt=0)
    history_hours: float = num(8.0, gt=0, le=240)
    consistency_ticks: int = num(12, ge=1, le=10000)
    consistency_alpha: float = num(1e-3, gt=0, lt=1)
    sigma_alpha: float = num(1.0, gt=0, le=10)
    sigma_beta: float = num(2.0, ge=0)
    sigma_kappa: float = num(1.0, ge=0)
    peer_blend: bool = True
    peer_prior_physics: float = num(0.9, gt=0, lt=1)
    peer_prior_hold: float | None = num(None, ge=0, lt=1)
    peer_evidence: float = num(1.0, ge=0, le=1)
    peer_forgetting: float = num(0.85, ge=0, le=1)
    band_conformal: bool = True
    band_step: float = num(0.3, gt=0, le=5)
    band_scale_min: float = num(0.5, gt=0, le=1)
    band_scale_max: float = num(5.0, ge=1, le=100)
    openloop_moisture_in_std: float = num(0.15, gt=0, lt=2)
    openloop_moisture_out_std: float = num(0.05, gt=0, lt=1)

    #: Keys that judged lab results here: the lab-result contract judges them once, for all.
    MOVED_KEYS: ClassVar[Mapping[str, str]] = {
        "lab_min": "the plant lab's envelope is estimator.lab_envelope_min; the published "
                   "estimate's range is estimator.moisture_out_min",
        "lab_max": "the plant lab's envelope is estimator.lab_envelope_max; the published "
                   "estimate's range is estimator.moisture_out_max"}

    def check(self) -> str | None:
        """Cross-field rules (called by ``build_section``); the message names the key."""
        if self.kind not in ESTIMATOR_KINDS:
            return f"kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {self.kind!r}"
        if self.moisture_in_max <= self.moisture_in_min:
            return (f"moisture_in_max must be > moisture_in_min ({self.moisture_in_min:g}), "
                    f"got {self.moisture_in_max:g}")
        if self.moisture_out_max <= self.moisture_out_min:
            return (f"moisture_out_max must be > moisture_out_min ({self.moisture_out_min:g}), "
                    f"got {self.moisture_out_max:g}")
        if self.lab_envelope_max <= self.lab_envelope_min:
            return (f"lab_envelope_max must be > lab_envelope_min ({self.lab_envelope_min:g}), "
                    f"got {self.lab_envelope_max:g}")
        if (self.peer_prior_hold is not None
                and self.peer_prior_physics + self.peer_prior_hold > 1.0 + 1e-9):
            return (f"peer_prior_hold must be at most 1 - peer_prior_physics "
                    f"({1.0 - self.peer_prior_physics:g}), got {self.peer_prior_hold:g}")
        if 2.5 * self.inlet_margin > self.moisture_in_max - self.moisture_in_min:
            return (f"inlet_margin must be below 0.4 of the inlet range, got "
                    f"{self.inlet_margin:g}")
        return None

    @property
    def discrepancy_floor(self) -> tuple[float, float, float, float]:
        """Floors of the four output error states' standard deviations (heat input, two
        channel offsets, bias) [K, K, K, kg/kg]."""
        t = self.T_std_floor
        return (t, t, t, self.moisture_std_floor)

    def walk_per_window(self, walk_per_sqrt_hour: float, window_s: float) -> float:
        """Random-walk standard deviation over one window of ``window_s`` seconds. [kg/kg]"""
        return walk_per_sqrt_hour * math.sqrt(window_s / 3600.0)

    def history_ticks(self, window_s: float) -> int:
        """Number of windows of ``window_s`` seconds the history keeps (at least 2)."""
        return max(2, int(math.ceil(self.history_hours * 3600.0 / window_s)))


def estimator_settings(cfg: PlantConfig) -> EstimatorSettings:
    """The validated ``[estimator]`` table of ``cfg`` (built once), or the defaults when it
    has none."""
    return section_of(cfg, "estimator", EstimatorSettings)
