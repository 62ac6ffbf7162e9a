"""What the sensor does with a calibration: the filter's prequential lab score on whole days.

A calibration is deployed for the estimator, which reads the inlet moisture from the
temperatures and corrects its outlet moisture with late lab results. A fit judged by its
held-out temperatures can make that estimator worse (the history benchmark on plant 6262: the
structure search adopted a longer cyclone hold-up on the temperatures while the held-out labs
went from 0.0076 to 0.0176 kg/kg). So a decision between two calibrations asks the estimator
itself: :func:`sensor_score` runs the UKF (its physics alone: no peers, no conformal band,
so the model and not the blend is judged) over each day, hands every lab result over
``delay_ticks`` after its sample window, as a plant's lab does, and before it is applied
scores the estimate the filter had published for that window: the log density of the result
under ``N(mean, sd^2 + lab_std^2)`` (a proper score: Gneiting and Raftery, JASA 102:359,
2007; prequential, Dawid, JRSS A 147:278, 1984: each result is predicted before it is seen),
and the error of the mean.

Both candidates carry their own model error learned on the history at their own parameters
(:func:`~.model_error_fit.fit_model_error`), as PARAMS.toml would deploy them.

Two calibrations are compared lab by lab (:func:`paired`): on the results both predicted, the
mean difference of their log densities and its standard error, and how many each failed to
predict (a tick that raised or published no band). A side is not credited for labs it failed
on, as a mean over its own successes alone would do.

Prequential in the lab results only: each result is predicted before the filter sees it, but
the parameters and the model error were fitted on histories that hold these days (the latest
days are history too), so the score is in-sample for the calibration.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from softsensor.calibration.dataset import Segment
from softsensor.errors import SoftsensorError
from softsensor.estimation.interface import LabResult, Window
from softsensor.estimation.lab_regression import LabRegression
from softsensor.estimation.model_error import ModelError
from softsensor.estimation.settings import EstimatorSettings, estimator_settings
from softsensor.estimation.ukf import UkfEstimator
from softsensor.jsonable import finite_or_none
from softsensor.plantconfig import DiscrepancyPrior, PlantConfig, with_table
from softsensor.signals import INPUT_NAMES, OUTPUT_NAMES
from softsensor.windows.accumulator import window_settings
from softsensor.windows.inputs import MEASURED_INPUTS

#: Latest days of the history the decision runs the filter on: the dryer's present, which
#: the deployed calibration continues from (two 48 h days: about 20 s of filtering).
SCORE_DAYS = 2
#: Windows after the sample's before its result is handed over (a lab's delay).
DELAY_TICKS = 1


@dataclass(frozen=True)
class SensorScore:
    """The filter's prequential lab score on some days: mean log density ``log_score``
    [-], the RMSE of its predictions ``rmse`` [kg/kg] and the results scored ``n``;
    ``per_lab``: each result's log density by ``"day:sample_id"`` (None: not predicted)."""

    log_score: float
    rmse: float
    n: int
    per_lab: Mapping[str, float | None] = field(default_factory=dict, repr=False)

    def as_dict(self) -> dict[str, float | int]:
        return {"log_score": self.log_score, "rmse": self.rmse, "n": self.n,
                "failed": sum(v is None for v in self.per_lab.values())}


@dataclass(frozen=True)
class Paired:
    """``a`` against ``b`` on the lab results both predicted: the mean difference of their
    log densities ``diff`` (positive: ``a`` better) and its standard error ``se`` [-], the
    results compared ``n``, and the results each failed to predict."""

    diff: float
    se: float
    n: int
    failed_a: int
    failed_b: int

    def as_dict(self) -> dict[str, float | int]:
        return {"diff": self.diff, "se": self.se, "n": self.n, "failed_a": self.failed_a,
                "failed_b": self.failed_b}


def not_worse(p: Paired) -> bool:
    """``a`` does at least as well as ``b`` (:func:`paired`): it failed to predict no more
    results, and its mean log density is not lower by more than the difference's standard
    error (a difference within it is a tie: deciding on it would be a coin flip)."""
    return p.failed_a <= p.failed_b and not p.diff < -p.se


def paired(a: SensorScore, b: SensorScore) -> Paired:
    """``a`` against ``b`` lab by lab (module docstring)."""
    both = [k for k, v in a.per_lab.items() if v is not None and b.per_lab.get(k) is not None]
    d = np.array([a.per_lab[k] - b.per_lab[k] for k in both], float)  # type: ignore[operator]
    se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else math.inf
    return Paired(float(np.mean(d)) if d.size else math.nan, se, int(d.size),
                  sum(v is None for v in a.per_lab.values()),
                  sum(v is None for v in b.per_lab.values()))


def day_windows(seg: Segment, scan_period_s: float) -> list[Window]:
    """The estimator's windows of a day: its inputs, temperatures, set point and bins, each
    window full of scans ``scan_period_s`` apart (a segment keeps means, not counts)."""
    out = []
    w_ns = seg.window_ns
    n_bins = seg.bins.shape[1]
    n_scans = max(1, round(seg.window / scan_period_s))
    for k in range(seg.n_windows):
        means: dict[str, float | None] = {n: finite_or_none(seg.U[k, i])
                                          for i, n in enumerate(INPUT_NAMES[:-1])}
        for c, name in enumerate(OUTPUT_NAMES[:2]):
            means[name] = finite_or_none(seg.Y[k, c])
        means["T_sp"] = finite_or_none(seg.T_sp[k])
        bins = {n: [finite_or_none(v) for v in seg.bins[k, :, i]]
                for i, n in enumerate(MEASURED_INPUTS)} if n_bins else {}
        start = seg.start_ns + k * w_ns
        out.append(Window(start, start + w_ns, means, n_scans,
                          {n: (n_scans if v is not None else 0) for n, v in means.items()},
                          bin_s=seg.window / n_bins if n_bins else 0.0, bins=bins))
    return out


def deployable(config: PlantConfig, theta: np.ndarray, model_error: ModelError,
               discrepancy: DiscrepancyPrior | None) -> PlantConfig:
    """``config`` as PARAMS.toml would deploy it: ``theta``, its model error and the
    discrepancy prior."""
    out = config.with_parameters(np.asarray(theta, float))
    out = with_table(out, "model_error", model_error.to_table())
    if discrepancy is not None:
        out = with_table(out, "discrepancy", discrepancy.as_table())
    return out


@dataclass
class DayRun:
    """One day filtered as :func:`sensor_score` runs it: per tick its window and the
    estimate published (mean and band sd [kg/kg], None where it published none), the day's
    lab results with the window each was sampled in, each result's log density under the
    estimate published for that window before it was handed over (None: not predicted), and
    the lab regression the day's peers run with (None: without)."""

    windows: list[Window]
    physics: list[tuple[float, float] | None]
    labs: list[LabResult]
    lab_window: np.ndarray
    log_density: list[float | None]
    errors: list[float | None]
    regression: LabRegression | None = None


def filter_day(config: PlantConfig, seg: Segment, s: EstimatorSettings,
               delay_ticks: int = DELAY_TICKS, regression: LabRegression | None = None
               ) -> DayRun:
    """Run the UKF with settings ``s`` over one day from a fresh start, every lab result
    handed over ``delay_ticks`` after its sample window, and score each result before it is
    applied (module docstring). ``regression`` is carried for the peers' replay
    (:mod:`.sensor_tuning`); the filter itself publishes what ``s`` says."""
    lab_var = s.lab_std ** 2
    est = UkfEstimator(config, s)
    windows = day_windows(seg, window_settings(config).scan_period_s)
    published: list[tuple[float, float] | None] = []
    labs: list[LabResult] = []
    logs: list[float | None] = []
    errs: list[float | None] = []
    due: dict[int, list[int]] = {}
    for j, k in enumerate(seg.lab_window):
        due.setdefault(int(k) + delay_ticks, []).append(j)
    order: list[int] = []
    for k, w in enumerate(windows):
        for j in due.get(k, []):
            pred = published[int(seg.lab_window[j])]
            value = float(seg.lab_value[j])
            lab = LabResult(int(seg.lab_time_ns[j]), value, str(seg.lab_id[j]), w.start_ns)
            order.append(j)
            labs.append(lab)
            if pred is not None:
                mean, sd = pred
                var = sd * sd + lab_var
                logs.append(-0.5 * (math.log(2 * math.pi * var) + (value - mean) ** 2 / var))
                errs.append(value - mean)
            else:
                logs.append(None)
                errs.append(None)
            est.add_lab(lab)
        try:
            e = est.tick(w)
            published.append((e.moisture_out, e.moisture_out_std)
                             if e.moisture_out is not None and e.moisture_out_std
                             else None)
        except (SoftsensorError, ArithmeticError, ValueError):
            published.append(None)
    lab_window = np.asarray([int(seg.lab_window[j]) for j in order], dtype=int)
    return DayRun(windows, published, labs, lab_window, logs, errs, regression)


def sensor_score(config: PlantConfig, days: Sequence[Segment],
                 delay_ticks: int = DELAY_TICKS) -> SensorScore:
    """The filter's prequential lab score on ``days`` (module docstring)."""
    s = replace(estimator_settings(config), peer_blend=False, band_conformal=False)
    logs: list[float] = []
    errs: list[float] = []
    per_lab: dict[str, float | None] = {}
    for i, seg in enumerate(days):
        run = filter_day(config, seg, s, delay_ticks)
        for lab, lp, err in zip(run.labs, run.log_density, run.errors, strict=True):
            per_lab[f"{i}:{lab.sample_id}"] = lp
            if lp is not None and err is not None:
                logs.append(lp)
                errs.append(err)
    if not logs:
        return SensorScore(-math.inf, math.nan, 0, per_lab)
    return SensorScore(float(np.mean(logs)), float(np.sqrt(np.mean(np.square(errs)))),
                       len(logs), per_lab)


def latest_days(days: Sequence[Segment], n: int = SCORE_DAYS) -> list[Segment]:
    """The ``n`` latest of ``days`` (by start), oldest first."""
    return sorted(days, key=lambda d: d.start_ns)[-n:]


__all__ = ["DELAY_TICKS", "SCORE_DAYS", "DayRun", "Paired", "SensorScore", "day_windows",
           "deployable", "filter_day",
           "latest_days", "not_worse", "paired", "sensor_score"]
