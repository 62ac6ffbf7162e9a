"""The diagnosis problem: a day's windows, the calibrated model, the split, the noise levels.

Everything an extension fit or a score needs sits in one :class:`Problem`:

* the calibrated model (``DryerModel`` of the calibrated config) and its parameters ``theta``;
* the day as model windows (:mod:`.day_windows`), the windows and lab alignment of calibration and
  the estimator: predictions run :func:`~softsensor.calibration.chunked_run.simulate_span`,
  window-end outputs against window means and ``moisture_out`` at each lab's sample time;
* the held-out :class:`Split`: windows ``[0, k_fit)`` and the labs sampled before
  ``split_ns`` are the *fit part*, the rest is *held out*; :meth:`Problem.reversed` is the
  other fold (fit on the late part, hold out the early one). An extension fit sees its fit
  part only; every RMSE, cost and gain in the report is measured on data the fit producing it
  did not see (:func:`~.verdict.cross_fitted`);
* the white noise level of each channel (:func:`noise_levels`: the fit part's window-to-window
  scatter of the temperatures, the lab noise), the calibration-error model's measurement
  noise;
* the calibration-error alternative (:mod:`.calibration_error`): the estimator's discrepancy
  states, with the sizes and correlation times of the calibration's ``[discrepancy]``, run
  through the residuals by a Kalman filter; fits and scores use the whitened residuals it
  leaves (:meth:`Problem.whitened`), so an extension is judged by what it explains beyond "the
  calibration is a little off";
* the baseline prediction: the calibrated open-loop model on the day's measured inputs with the
  nominal inlet moisture, as ``validate`` runs it (the report's baseline); with a history
  (PARAMS.toml's ``[model_error]``), at the history's typical inlet moisture plus what the
  history says the model misses at each window's operating point (:func:`normal_offsets`),
  so that the day is judged against the plant's normal, and every extension on top of it.

Channels are ``T_dryer_out`` and ``T_cyclone_out`` (window means against the model's
window-end values, [K]) and ``moisture_out`` (lab results against the model at the sample
time, [kg/kg]), in :data:`~softsensor.signals.OUTPUT_NAMES` order.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass, field

import numpy as np

from softsensor.calibration.chunked_run import lab_values_at, simulate_span, window_start_states
from softsensor.calibration.dataset import LabPoints
from softsensor.calibration.open_loop_errors import normal_offsets
from softsensor.diagnosis.calibration_error import CalibrationErrorModel
from softsensor.diagnosis.day_windows import MODEL_LAB_STD, DayWindows
from softsensor.errors import SoftsensorError
from softsensor.estimation.model_error import ModelError, model_error_of
from softsensor.model import DryerModel
from softsensor.plantconfig import PlantConfig
from softsensor.signals import OUTPUT_NAMES

#: Default fraction of the day's windows in the fit part.
DEFAULT_FIT_FRACTION = 0.6
#: Fit fractions the split may move to so that both parts hold lab results.
FIT_FRACTION_RANGE = (0.5, 0.7)
#: Lab results wanted in each part of the split.
MIN_LABS_PER_PART = 3
#: Floor of a temperature channel's noise level (below the sensors' resolution). [K]
MIN_TEMPERATURE_NOISE = 0.01


@dataclass(frozen=True)
class Split:
    """Fit part and held-out part of a day.

    Attributes
    ----------
    k_fit : int
        The split: windows ``[0, k_fit)`` form the *early* part, ``[k_fit, K)`` the *late*
        part. The fit part is the early one, unless ``reverse``.
    split_ns : int
        End of window ``k_fit - 1``; labs stamped before it belong to the early part. [ns]
    lab_fit : numpy.ndarray of bool, shape (L,)
        Lab results in the fit part.
    note : str
        How the split was chosen (for the report).
    reverse : bool
        The fit part is the late part and the early part is held out (the second fold of
        the cross-fitting in :mod:`.verdict`).
    """

    k_fit: int
    split_ns: int
    lab_fit: np.ndarray
    note: str
    reverse: bool = False

    @property
    def lab_held(self) -> np.ndarray:
        return ~self.lab_fit

    @property
    def fit_windows(self) -> slice:
        """The fit part's windows."""
        return slice(self.k_fit, None) if self.reverse else slice(0, self.k_fit)

    @property
    def held_windows(self) -> slice:
        """The held-out part's windows."""
        return slice(0, self.k_fit) if self.reverse else slice(self.k_fit, None)

    def sim_end(self, n_windows: int) -> int:
        """Windows a model run must cover to reach the end of the fit part."""
        return n_windows if self.reverse else self.k_fit

    def reversed(self) -> Split:
        """The other fold: fit on the held-out part, hold out the fit part."""
        return Split(self.k_fit, self.split_ns, ~self.lab_fit, self.note, not self.reverse)


def choose_split(windows: DayWindows, fraction: float = DEFAULT_FIT_FRACTION,
                 min_labs: int = MIN_LABS_PER_PART) -> Split:
    """Split at ``fraction`` of the windows, moved within :data:`FIT_FRACTION_RANGE` (nearest
    first) when needed so that each part holds at least ``min_labs`` lab results."""
    K = windows.n_windows
    lo, hi = FIT_FRACTION_RANGE
    candidates = [fraction] + [f for d in np.arange(0.01, 0.21, 0.01)
                               for f in (fraction - d, fraction + d) if lo <= f <= hi]
    best = None
    for f in candidates:
        k_fit = int(np.clip(round(f * K), 1, K - 1))
        split_ns = int(windows.end_ns[k_fit - 1])
        lab_fit = windows.lab_time_ns < split_ns
        n_fit, n_held = int(lab_fit.sum()), int((~lab_fit).sum())
        if best is None:
            best = (k_fit, split_ns, lab_fit, n_fit, n_held)
        if n_fit >= min_labs and n_held >= min_labs:
            note = (f"fit on the first {k_fit} of {K} windows ({k_fit / K:.0%}, "
                    f"{n_fit} lab results), held out the last {K - k_fit} ({n_held} lab "
                    f"results)")
            return Split(k_fit, split_ns, lab_fit, note)
    k_fit, split_ns, lab_fit, n_fit, n_held = best  # type: ignore[misc]
    note = (f"fit on the first {k_fit} of {K} windows ({n_fit} lab results), held out the last "
            f"{K - k_fit} ({n_held} lab results): fewer than {min_labs} lab results in a part, "
            f"so the moisture channel's held-out numbers rest on few samples")
    return Split(k_fit, split_ns, lab_fit, note)


@dataclass(frozen=True)
class Prediction:
    """Model outputs over the whole day.

    ``Y`` (K, 3) are window-end outputs in ``OUTPUT_NAMES`` order; ``lab`` (L,) the model's
    outlet moisture at the lab sample times the prediction uses (an extension may move them),
    NaN for a lab beyond a run cut short (``k_end``).
    """

    Y: np.ndarray
    lab: np.ndarray


@dataclass(frozen=True)
class Residuals:
    """Measured minus model: ``T`` (K, 2) [K], NaN where a window lacks a measurement, and
    ``lab`` (L,) [kg/kg]."""

    T: np.ndarray
    lab: np.ndarray


@dataclass
class Problem:
    """One diagnosis: model, day, split, noise levels, the baseline and the reference."""

    config: PlantConfig
    model: DryerModel
    windows: DayWindows
    split: Split
    theta: np.ndarray
    lab_noise: float
    sigma: np.ndarray = field(init=False)
    baseline: Prediction = field(init=False)
    calibration_error: CalibrationErrorModel = field(init=False)
    normal: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.theta = np.asarray(self.theta, float)
        self.normal = normal_offsets(self.config, self.windows.segment)
        self.baseline = self.predict()
        self.sigma = noise_levels(self.residuals(self.baseline), self.split, self.lab_noise,
                                  model_error_of(self.config))
        self.calibration_error = CalibrationErrorModel.from_config(self.config, self.sigma)

    def reversed(self) -> Problem:
        """The same problem with the other fold (:meth:`Split.reversed`): extensions fitted on
        it are fitted on the held-out part. The noise levels stay those of this problem's fit
        part, so that both folds weigh the channels alike."""
        other = copy.copy(self)
        other.split = self.split.reversed()
        return other

    # ------------------------------------------------------------------ model runs
    def lab_points(self, shift_ns: float = 0.0, U: np.ndarray | None = None,
                   bins: np.ndarray | None = None) -> LabPoints:
        """Where the labs meet the model, their sample times moved by ``shift_ns``, with
        inputs ``U`` and sub-window ``bins`` (default the day's)."""
        return self.windows.segment.lab_points(shift_ns, U, bins)

    def predict(self, U: np.ndarray | None = None, theta: np.ndarray | None = None,
                aux: np.ndarray | None = None, k_end: int | None = None,
                labs: LabPoints | None = None) -> Prediction:
        """The model over the first ``k_end`` windows (default all) from the steady state of
        window 0: inputs ``U`` (default the day's; the labs then take theirs from ``U`` too),
        parameters ``theta`` (7,) or per window (K, 7), extension coefficients ``aux``. Raises
        :class:`~softsensor.errors.SoftsensorError` when the model fails."""
        seg = self.windows.segment
        K = seg.n_windows if k_end is None else int(k_end)
        if labs is None:
            labs = seg.default_lab_points() if U is None else seg.lab_points(U=U)
        th = self.theta if theta is None else np.asarray(theta, float)
        Y, lab, _ = simulate_span(self.model, seg, th[None], 0, K, None, U=U, aux=aux,
                                  labs=labs)
        inside = labs.window < K
        out = np.full(labs.window.size, np.nan)
        out[inside] = lab[0] + self.normal[labs.window[inside], 2]
        if not (np.all(np.isfinite(Y)) and np.all(np.isfinite(lab))):
            raise SoftsensorError("the model failed on the day with this extension")
        return Prediction(Y[0] + self.normal[:K], out)

    @functools.cached_property
    def start_states(self) -> np.ndarray:
        """The baseline model's state at the start of every window (K, n_state)."""
        return window_start_states(self.model, self.windows.segment, self.theta)

    def baseline_labs(self, labs: LabPoints) -> np.ndarray:
        """The baseline model's ``moisture_out`` at other lab points (moved sample times),
        with the plant's normal at their windows."""
        return (lab_values_at(self.model, self.start_states, labs, self.theta)
                + self.normal[labs.window, 2])

    # ------------------------------------------------------------------ residuals and fit
    def residuals(self, pred: Prediction) -> Residuals:
        """Measured minus predicted, over the windows and labs the prediction covers."""
        k = len(pred.Y)
        return Residuals(self.windows.Y[:k] - pred.Y[:, :2], self.windows.lab_value - pred.lab)

    def fit_part(self, pred: Prediction) -> list[np.ndarray]:
        """Fit-part residuals per channel (NaN dropped): two temperature arrays [K] and the
        lab array [kg/kg]."""
        r = self.residuals(pred)
        w = self.split.fit_windows
        parts = [r.T[w, 0], r.T[w, 1], r.lab[self.split.lab_fit]]
        return [p[np.isfinite(p)] for p in parts]

    def held_out_part(self, pred: Prediction) -> list[np.ndarray]:
        """Held-out residuals per channel, as :meth:`fit_part`."""
        r = self.residuals(pred)
        w = self.split.held_windows
        parts = [r.T[w, 0], r.T[w, 1], r.lab[self.split.lab_held]]
        return [p[np.isfinite(p)] for p in parts]

    def whitened(self, pred: Prediction, part: str = "fit") -> list[np.ndarray]:
        """``pred``'s residuals through the calibration-error alternative
        (:class:`~.calibration_error.CalibrationErrorModel`): the whitened one-step prediction
        errors per channel (NaN dropped), over the fit part (``"fit"``, the filter started at
        its first window), the held-out part (``"held"``) or the whole day (``"all"``)."""
        r = self.residuals(pred)
        K = len(pred.Y)
        if part == "fit":
            w, labs = self.split.fit_windows, self.split.lab_fit
        elif part == "held":
            w, labs = self.split.held_windows, self.split.lab_held
        elif part == "all":
            w, labs = slice(0, K), np.ones(r.lab.size, bool)
        else:
            raise ValueError(f"part must be fit, held or all, not {part!r}")
        wT = self.calibration_error.whiten_temperatures(r.T[w])
        t_s = (self.windows.lab_time_ns[labs] - self.windows.start_ns) / 1e9
        wl = self.calibration_error.whiten_labs(r.lab[labs], t_s)
        parts = [wT[:, 0], wT[:, 1], wl]
        return [p[np.isfinite(p)] for p in parts]

    def lab_chi2(self, lab: np.ndarray) -> float:
        """Sum of squared whitened fit-part lab residuals of model values ``lab`` (L,) (the
        lab channel's part of :meth:`chi2`); infinite when a value is missing."""
        r = self.windows.lab_value - np.asarray(lab, float)
        keep = self.split.lab_fit
        if not np.all(np.isfinite(r[keep])):
            return float("inf")
        t_s = (self.windows.lab_time_ns[keep] - self.windows.start_ns) / 1e9
        w = self.calibration_error.whiten_labs(r[keep], t_s)
        return float(w @ w)

    def fit_residual_vector(self, pred: Prediction) -> np.ndarray:
        """The whitened fit-part residuals of ``pred`` as one vector (generalised least
        squares under the calibration-error alternative; its squared norm is :meth:`chi2`)."""
        return np.concatenate(self.whitened(pred, "fit"))

    def chi2(self, pred: Prediction) -> float:
        """Fit objective: the sum of squared whitened fit-part residuals, minus twice the
        log-likelihood of the calibration-error alternative up to a constant (the paper's
        eq. 4 is used for scores)."""
        r = self.fit_residual_vector(pred)
        return float(r @ r)


def noise_levels(res: Residuals, split: Split, lab_noise: float,
                 model_error: ModelError | None = None) -> np.ndarray:
    """Noise level of each channel: with a history, the white residual it left on each
    channel (the plant's normal); else from the fit part of the baseline residuals.

    Temperatures: the robust spread of first differences, ``1.4826 MAD(diff r) / sqrt(2)``,
    which sees the window-to-window noise and not slow structure (a model error that a trend,
    an offset or a daily cycle explains). Labs, a few a day, are too sparse for that: their
    noise is the configured lab standard deviation (``estimator.lab_std``) combined with the
    moisture's movement inside a window (:data:`~.day_windows.MODEL_LAB_STD`). [K, K, kg/kg]
    """
    if model_error is not None:
        return np.array([max(model_error.channel(c).noise, floor) for c, floor in
                         zip(OUTPUT_NAMES, (MIN_TEMPERATURE_NOISE, MIN_TEMPERATURE_NOISE,
                                            lab_noise), strict=True)])
    out = np.empty(len(OUTPUT_NAMES))
    for c in range(2):
        r = res.T[split.fit_windows, c]
        d = np.diff(r[np.isfinite(r)])
        s = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0) if d.size > 4 else 0.5
        out[c] = max(float(s), MIN_TEMPERATURE_NOISE)
    out[2] = float(np.hypot(lab_noise, MODEL_LAB_STD))
    return out
