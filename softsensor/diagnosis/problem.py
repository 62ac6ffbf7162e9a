"""The diagnosis problem: a day's windows, the calibrated model, the split, the noise levels.

Everything an extension fit or a score needs sits in one :class:`Problem`:

* the calibrated model (``DryerModel`` of the calibrated config) and its parameters ``theta``;
* the day as model windows (:mod:`.windows`);
* the held-out :class:`Split`: windows ``[0, k_fit)`` and the labs sampled before
  ``split_ns`` are the *fit part*, the rest is *held out*; :meth:`Problem.reversed` is the
  other fold (fit on the late part, hold out the early one). An extension fit sees its fit
  part only; every RMSE, cost and gain in the report is measured on data the fit producing it
  did not see (:func:`~.verdict.cross_fitted`);
* the noise level of each channel: :func:`noise_levels`, raised to ``sigma_floor`` when given
  (the calibrated model's RMSE on its calibration data: a model does not fit a new day better
  than the day it was calibrated on, and the floor keeps calibration error from passing for a
  cause). It weights the channels in the fit objective :meth:`Problem.chi2` and in the
  log-likelihoods of :mod:`.verdict`;
* the baseline prediction: the calibrated open-loop model on the day's measured inputs with the
  nominal inlet moisture.

Channels are ``T_dryer_out`` and ``T_cyclone_out`` (window means against the model's
window-end values, [K]) and ``moisture_out`` (lab results against the model interpolated at the
stamped sample time, [kg/kg]), in :data:`~softsensor.signals.OUTPUT_NAMES` order.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from softsensor.diagnosis.windows import MODEL_LAB_STD, DayWindows, lab_model_values
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
    outlet moisture at the lab sample times the prediction uses (an extension may move them).
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
    """One diagnosis: model, day, split, noise levels and the baseline prediction."""

    config: PlantConfig
    model: DryerModel
    windows: DayWindows
    split: Split
    theta: np.ndarray
    lab_noise: float
    sigma_floor: np.ndarray | None = None
    sigma: np.ndarray = field(init=False)
    baseline: Prediction = field(init=False)

    def __post_init__(self) -> None:
        self.theta = np.asarray(self.theta, float)
        self.baseline = self.predict(self.windows.U)
        self.sigma = noise_levels(self.residuals(self.baseline), self.split, self.lab_noise)
        if self.sigma_floor is not None:
            floor = np.asarray(self.sigma_floor, float)
            self.sigma = np.maximum(self.sigma, np.where(np.isfinite(floor), floor, 0.0))

    def reversed(self) -> Problem:
        """The same problem with the other fold (:meth:`Split.reversed`): extensions fitted on
        it are fitted on the held-out part. The noise levels stay those of this problem's fit
        part, so that both folds weigh the channels alike."""
        other = copy.copy(self)
        other.split = self.split.reversed()
        return other

    # ------------------------------------------------------------------ model runs
    def simulate(self, U: np.ndarray, theta: np.ndarray | None = None,
                 aux: np.ndarray | None = None, k_end: int | None = None) -> np.ndarray:
        """Model outputs (k_end, 3) for inputs ``U`` from the steady state of window 0."""
        k_end = self.windows.n_windows if k_end is None else k_end
        th = self.theta if theta is None else np.asarray(theta, float)
        if th.ndim == 2:
            th = th[:k_end]
        if aux is not None and np.ndim(aux) == 2:
            aux = aux[:k_end]
        Y, _ = self.model.simulate(U[:k_end], th, aux=aux)
        return Y

    def predict(self, U: np.ndarray, theta: np.ndarray | None = None,
                aux: np.ndarray | None = None, k_end: int | None = None,
                lab_shift_ns: float = 0.0) -> Prediction:
        """Simulate and look up the lab values (sample times moved by ``lab_shift_ns``)."""
        Y = self.simulate(U, theta, aux, k_end)
        return self.prediction(Y, lab_shift_ns)

    def prediction(self, Y: np.ndarray, lab_shift_ns: float = 0.0) -> Prediction:
        """Wrap outputs ``Y`` (k, 3), k <= K, with lab values at the shifted sample times."""
        w = self.windows
        ts = w.lab_time_ns.astype(float) + lab_shift_ns
        return Prediction(Y, lab_model_values(w.end_ns[:len(Y)], Y[:, 2], w.window_s, ts))

    # ------------------------------------------------------------------ residuals and fit
    def residuals(self, pred: Prediction) -> Residuals:
        """Measured minus predicted, over the windows and labs the prediction covers."""
        k = len(pred.Y)
        return Residuals(self.windows.Y[:k] - pred.Y[:, :2], self.windows.lab_value - pred.lab)

    def chi2(self, pred: Prediction) -> float:
        """Fit objective: squared residuals over the fit part, each channel divided by its
        noise level (a weighted least-squares cost; the paper's eq. 4 is used for scores)."""
        return float(self.chi2_channels(pred).sum())

    def chi2_channels(self, pred: Prediction) -> np.ndarray:
        """The fit objective per channel (3,), ``OUTPUT_NAMES`` order."""
        r = self.residuals(pred)
        T = r.T[self.split.fit_windows] / self.sigma[:2]
        lab = r.lab[self.split.lab_fit] / self.sigma[2]
        return np.array([np.nansum(T[:, 0] ** 2), np.nansum(T[:, 1] ** 2), np.sum(lab**2)])

    def fit_part(self, pred: Prediction) -> list[np.ndarray]:
        """Fit-part residuals per channel (NaN windows dropped): two temperature arrays [K]
        and the lab array [kg/kg]."""
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

    def fit_residual_vector(self, pred: Prediction) -> np.ndarray:
        """The normalised fit-part residuals as one vector (for ``least_squares``)."""
        r = self.residuals(pred)
        T = (r.T[self.split.fit_windows] / self.sigma[:2]).ravel()
        lab = r.lab[self.split.lab_fit] / self.sigma[2]
        return np.concatenate([T[np.isfinite(T)], lab])


def noise_levels(res: Residuals, split: Split, lab_noise: float) -> np.ndarray:
    """Noise level of each channel, from the fit part of the baseline residuals.

    Temperatures: the robust spread of first differences, ``1.4826 MAD(diff r) / sqrt(2)``,
    which sees the window-to-window noise and not slow structure (a model error that a trend,
    an offset or a daily cycle explains). Labs, a few a day, are too sparse for that: their
    noise is the configured lab standard deviation (``estimator.lab_std``) combined with the
    moisture's movement inside a window (:data:`~.windows.MODEL_LAB_STD`). [K, K, kg/kg]
    """
    out = np.empty(len(OUTPUT_NAMES))
    for c in range(2):
        r = res.T[split.fit_windows, c]
        d = np.diff(r[np.isfinite(r)])
        s = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0) if d.size > 4 else 0.5
        out[c] = max(float(s), MIN_TEMPERATURE_NOISE)
    out[2] = float(np.hypot(lab_noise, MODEL_LAB_STD))
    return out
