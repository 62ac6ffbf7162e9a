"""The calibrated model's open-loop errors on a day: the one number per channel that
``validate`` puts first and ``diagnose`` reports as its baseline (issue 28 item 4, issue 30
item 4: the two verbs printed 2.85 and 0.72 % points for one day and one parameter file).

"Open loop" is the calibrated model as the product deploys it, run on the day's measured
inputs with nothing read from the day's outputs:

* the inlet moisture held at the calibration's level: PARAMS.toml's ``[model_error]``
  ``moisture_in`` (the history's typical inlet moisture, where the estimator starts) when
  the file has one, else the config's ``nominal.moisture_in``;
* plus, with a ``[model_error]``, what the history says the model misses at each window's
  operating point (the learned discrepancy with the mean day offset, :func:`normal_offsets`):
  the plant's normal, which the estimator adds to its measurement model and the diagnosis
  judges a day against.

:func:`prepared` applies both to a :class:`~.dataset.Segment` (the normal is taken off the
measurements, so that measured minus model is measured minus model-plus-normal and every
scorer of :mod:`.cost` and :mod:`.objective` sees the same residuals), and
:func:`open_loop_fit` scores it. The verdict against the calibration's own held-out error is
:func:`reference_rmse` and :func:`channel_verdicts`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.calibration.chunked_run import simulate_segments
from softsensor.calibration.cost import (
    Fit,
    ModelRun,
    fit_from_residuals,
    residuals,
    weighted_rmse,
)
from softsensor.calibration.dataset import Segment
from softsensor.calibration.model_error_fit import at_inlet_moisture, feature_columns
from softsensor.estimation.model_error import model_error_of
from softsensor.model import DryerModel
from softsensor.plantconfig import PlantConfig
from softsensor.signals import OUTPUT_NAMES

#: A day's RMSE up to this multiple of the calibration's held-out error is within what one
#: day scatters about it: the reference is a root mean square over the history's days, and
#: one day's offset drawn two standard deviations out (one day in twenty) doubles its part.
WITHIN_SPREAD = 2.0


def inlet_level(config: PlantConfig) -> float:
    """The calibration's inlet moisture [kg/kg]: ``[model_error]`` ``moisture_in`` when
    the config carries one, else ``nominal.moisture_in``."""
    me = model_error_of(config)
    return float(config.nominal.moisture_in if me is None else me.moisture_in)


def normal_offsets(config: PlantConfig, seg: Segment) -> np.ndarray:
    """What the history says the calibrated model misses at every window's operating point
    (K, 3) in ``OUTPUT_NAMES`` order (:mod:`softsensor.estimation.model_error`: the learned
    discrepancy with the mean day offset); zeros without a ``[model_error]``."""
    me = model_error_of(config)
    if me is None:
        return np.zeros((seg.n_windows, len(OUTPUT_NAMES)))
    phi = me.phi_matrix(feature_columns(seg))
    return np.column_stack([me.offset(c, phi) for c in OUTPUT_NAMES])


def prepared(config: PlantConfig, seg: Segment) -> Segment:
    """``seg`` as the open-loop model of ``config`` meets it (module docstring): the inlet
    moisture at :func:`inlet_level`, the measurements less :func:`normal_offsets`."""
    seg = at_inlet_moisture(seg, inlet_level(config))
    if model_error_of(config) is None:
        return seg
    normal = normal_offsets(config, seg)
    Y = seg.Y.copy()
    Y[:, :2] -= normal[:, :2]
    lab = seg.lab_value - normal[seg.lab_window, 2]
    return dataclasses.replace(seg, Y=Y, lab_value=lab)


def displayed(config: PlantConfig, raw: Segment, run: ModelRun) -> ModelRun:
    """``run`` (model outputs on :func:`prepared` ``raw``) with the history's normal added
    back, to be drawn against ``raw``'s measurements."""
    normal = normal_offsets(config, raw)
    Y = run.Y.copy()
    Y[:, :, :2] += normal[None, :, :2]
    return ModelRun(Y, run.lab + normal[raw.lab_window, 2][None])


def open_loop_fit(config: PlantConfig, segments: Sequence[Segment],
                  model: DryerModel | None = None) -> Fit:
    """Per-channel RMSE and eq. 4 cost of the open-loop model of ``config`` (its parameters,
    inlet level and normal: module docstring) over ``segments`` as read from the days (not
    yet :func:`prepared`), pooled. The figure ``validate`` and ``diagnose`` both report."""
    model = model if model is not None else DryerModel(config)
    segs = [prepared(config, s) for s in segments]
    runs = simulate_segments(model, segs, config.parameter_vector())
    res = [residuals(run, seg) for run, seg in zip(runs, segs, strict=True)]
    return fit_from_residuals(res, config.cost.weights())[0]


@dataclass(frozen=True)
class Reference:
    """What the calibration expects of the open-loop model on a day it was not fitted on,
    per channel [K, K, kg/kg], and where that number comes from."""

    rmse: dict[str, float]
    source: str

    def as_dict(self) -> dict[str, Any]:
        return {"rmse": dict(self.rmse), "source": self.source}


def reference_rmse(config: PlantConfig, fit_section: Mapping[str, Any] | None = None
                   ) -> Reference | None:
    """The calibration's own held-out error of the open-loop model, per channel.

    With a ``[model_error]``: ``sqrt(rmse_held_out^2 + day_sd^2)``. ``rmse_held_out`` is the
    error the learned normal left on history days it was not fitted on, within each day (the
    day's mean removed); a new day also sits at its own level, whose spread about the normal
    the history measured (``day_sd``). Without one, the ``[fit.validation]``
    ``open_loop_rmse`` of a calibration that held data out (the same model: no normal, the
    config's nominal inlet). None when the file holds neither.
    """
    me = model_error_of(config)
    if me is not None:
        return Reference({n: math.hypot(me.channel(n).rmse_held_out, me.channel(n).day_sd)
                          for n in OUTPUT_NAMES},
                         "[model_error]: held-out RMSE within a day with the day-to-day "
                         "spread of its level")
    val = (fit_section or {}).get("validation")
    held = val.get("open_loop_rmse") if isinstance(val, Mapping) else None
    if isinstance(held, Mapping) and all(isinstance(held.get(n), (int, float))
                                         for n in OUTPUT_NAMES):
        return Reference({n: float(held[n]) for n in OUTPUT_NAMES},
                         "[fit.validation]: open-loop RMSE on the calibration's held-out data")
    return None


def channel_verdicts(rmse: Mapping[str, float], ref: Reference | None
                     ) -> dict[str, dict[str, Any]]:
    """Per channel: the ratio of ``rmse`` to the reference and its verdict, ``within``
    (at most 1), ``spread`` (up to :data:`WITHIN_SPREAD`: what one day scatters) or
    ``worse`` (the model does not hold on these data); ``unknown`` without a reference or a
    sample."""
    out = {}
    for n in OUTPUT_NAMES:
        r = float(rmse[n])
        ref_n = None if ref is None else ref.rmse.get(n)
        if ref_n is None or not (ref_n > 0 and math.isfinite(r)):
            out[n] = {"ratio": None, "verdict": "unknown"}
            continue
        ratio = r / ref_n
        out[n] = {"ratio": ratio, "verdict": ("within" if ratio <= 1.0 else "spread"
                                              if ratio <= WITHIN_SPREAD else "worse")}
    return out


def open_loop_summary(config: PlantConfig, segments: Sequence[Segment],
                      fit_section: Mapping[str, Any] | None = None,
                      model: DryerModel | None = None) -> dict[str, Any]:
    """The open-loop errors of ``config`` on ``segments`` (:func:`open_loop_fit`) with the
    inlet level, whether the history's normal is in, the calibration's reference
    (:func:`reference_rmse`, from ``fit_section``: PARAMS.toml's ``[fit]``) and each
    channel's verdict: the ``open_loop`` object of ``validate``'s JSON and of REPORT.json,
    built here once for both verbs."""
    fit = open_loop_fit(config, segments, model)
    ref = reference_rmse(config, fit_section)
    return {"rmse": dict(fit.rmse), "cost": fit.cost, "samples": dict(fit.n),
            "weighted_rmse": weighted_rmse(fit, config.cost.weights()),
            "inlet_moisture": inlet_level(config), "normal": model_error_of(config) is not None,
            "reference": None if ref is None else ref.as_dict(),
            "verdict": channel_verdicts(fit.rmse, ref)}


__all__ = ["WITHIN_SPREAD", "Reference", "channel_verdicts", "displayed", "inlet_level",
           "normal_offsets", "open_loop_fit", "open_loop_summary", "prepared", "reference_rmse"]
