"""From a tick's posterior to the published estimate: health, the guard and its fallback, the
body of ``/softsensor/estimate`` (CONTRACT section 2).

:func:`publish` is pure: it is handed the posterior of :func:`~.ukf_step.step` and what it
needs of the history (:class:`TickContext`: the tick's window and labs, the innovations of
the previous ticks, the latest lab result applied so far) and returns the body.

Health: ``stale`` for a stale window (predict only); ``degraded`` when the model failed, when
the innovations of the last ``estimator.consistency_ticks`` fail the chi-square test of
:mod:`.consistency`, or when the guard fires; else ``ok``.

The guard: when the model has lost the plant, its outlet moisture is nonsense however the
filter bends. The tick then publishes a *lab-anchored* ``moisture_out``: the latest lab result,
with a band ``sqrt(lab_std^2 + jitter^2 + fallback_drift^2 * hours since it was sampled)``,
``fallback`` true, health ``degraded`` and the reason. The model has lost the plant when a
model solve fails, when the inlet moisture sits at a bound of its range, or when the heat
input's offset is further than ``guard_sigma`` of its prior standard deviations from zero.
An outlet-moisture bias beyond that, or a temperature channel's own offset (a suspect
sensor), degrade the health with the reason while the estimate is kept (measured on the
independent plant: with the bias in the guard, the flat last lab replaced the filter on half
of the input-lag, lab-delay and chip-batch days and did worse than the filter there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from softsensor.estimation.consistency import Innovation, chi_square_test
from softsensor.estimation.interface import LabResult, Window
from softsensor.estimation.settings import EstimatorSettings
from softsensor.estimation.state_space import (
    STATE_NAMES,
    STATE_UNITS,
    X_BIAS,
    X_GAIN,
    X_HEAT,
    X_IN,
    X_TCYC,
    X_TDRY,
)
from softsensor.estimation.ukf_step import FilterModel, Posterior, inlet_moments
from softsensor.jsonable import finite_or_none
from softsensor.signals import OUTPUT_NAMES

_MO = OUTPUT_NAMES.index("moisture_out")


@dataclass(frozen=True)
class TickContext:
    """What publication needs of the estimator's history for one tick."""

    window: Window
    held: tuple[str, ...]
    labs: tuple[LabResult, ...]
    recent: tuple[Innovation, ...]
    latest_lab: LabResult | None


def _beyond(filt: FilterModel, x: np.ndarray, i: int) -> str:
    """Error state ``i`` further than ``guard_sigma`` of its prior from zero, in words ('':
    it is not)."""
    name = STATE_NAMES[i]
    sd = filt.priors.sd(name)
    z = x[i] / sd
    if abs(z) <= filt.settings.guard_sigma:
        return ""
    unit = STATE_UNITS[name]
    return (f"{name} {x[i]:+.3g} {unit} is {abs(z):.1f} times the model error expected "
            f"({sd:.3g} {unit}, {filt.priors.source})")


def lost(filt: FilterModel, post: Posterior) -> str:
    """Why the model has lost the plant ('' when it has not): the guard's rules. The model
    failed, the inlet moisture sits at a bound of its range, or the energy balance is off
    by far more than expected (the heat input's offset): then nothing the model says of the
    outlet moisture can be trusted. An outlet-moisture bias beyond its prior is not a lost
    model: the bias is the lab-tracked correction doing its job (a chip batch steps the
    drying rate, a lab slip), so it degrades the health (:func:`suspect`) and the filter's
    estimate stays published, which tracks the labs better than the last one alone."""
    if post.failure:
        return "the model could not be solved"
    x = post.x
    if filt.inlet.near_bound(float(x[X_IN])):
        X = float(filt.inlet.forward(x[X_IN]))
        return (f"the inlet moisture sits at the bound of its range ({X:.2f} kg/kg in "
                f"[{filt.inlet.lo:g}, {filt.inlet.hi:g}])")
    return _beyond(filt, x, X_HEAT)


def suspect(filt: FilterModel, x) -> str:
    """What degrades the health without replacing the estimate ('' when nothing does): an
    outlet-moisture bias beyond ``guard_sigma`` of its prior (the plant's outlet moisture is
    away from what the model and its history expect), and a thermometer that reads off the
    other: the two channels' own offsets differ by more than ``guard_sigma`` standard
    deviations of their difference (their priors' as if independent), and the one further
    from zero in its own prior's units is named.

    The difference, not each offset alone, because a model that misses the plant moves both
    outlet temperatures alike (one energy balance): on the independent plant's clean days
    each channel's offset reached 1.2 to 1.9 K, 4 to 7 times its day-to-day spread, while
    their difference stayed within 1.1 K; thermometer offsets of 2.2 to 5 K made it 1.9 to
    5.5 K (seed 4242, 2 plants)."""
    out = []
    bias = _beyond(filt, x, X_BIAS)
    if bias:
        out.append(f"{bias}: the outlet moisture follows the labs more than the model")
    sd = {i: filt.priors.sd(STATE_NAMES[i]) for i in (X_TDRY, X_TCYC)}
    diff = float(x[X_TDRY] - x[X_TCYC])
    z = diff / math.hypot(sd[X_TDRY], sd[X_TCYC])
    if abs(z) > filt.settings.guard_sigma:
        i, o = ((X_TDRY, X_TCYC) if abs(x[X_TDRY]) / sd[X_TDRY] >= abs(x[X_TCYC]) / sd[X_TCYC]
                else (X_TCYC, X_TDRY))
        name, other = (STATE_NAMES[k].removesuffix("_offset") for k in (i, o))
        out.append(f"{name} reads {x[i]:+.2f} K from the model where {other} reads "
                   f"{x[o]:+.2f} K ({abs(z):.1f} times the difference expected): check its "
                   f"sensor")
    return "; ".join(out)


def fallback(filt: FilterModel, ctx: TickContext) -> tuple[float, float, str] | None:
    """The lab-anchored estimate: the latest lab result applied so far, its band widened
    with the time since (None without one)."""
    latest = ctx.latest_lab
    if latest is None:
        return None
    std = fallback_std(filt.settings, ctx.window.end_ns - latest.sample_time_ns)
    return float(latest.moisture_out), std, latest.sample_id


def fallback_std(s: EstimatorSettings, age_ns: int) -> float:
    """Band sd of a lab result ``age_ns`` after its sample [kg/kg]: the lab's noise, the
    outlet's jitter and a drift growing with the hours since (the fallback's, and the held
    lab's among the peers)."""
    hours = max(age_ns, 0) / 3.6e12
    return math.sqrt(s.lab_std**2 + s.moisture_out_jitter_std**2 + s.fallback_drift**2 * hours)


def health(filt: FilterModel, ctx: TickContext, post: Posterior) -> tuple[str, str]:
    """Status and detail before the guard: stale, degraded by a failed model, or the
    chi-square test of the last ``consistency_ticks`` innovations."""
    w = ctx.window
    if w.stale:
        reasons = "; ".join(f"{key}: {v}" for key, v in w.reasons.items())
        return "stale", "stale window, predicting without correction" + (
            f": {reasons}" if reasons else "")
    if post.failure:
        return "degraded", post.failure
    verdict = chi_square_test([*ctx.recent, post.innovation], filt.settings.consistency_alpha)
    detail = verdict.detail
    if ctx.held:
        detail += f"; holding last value of {', '.join(ctx.held)}"
    return verdict.status, detail


def guard(filt: FilterModel, ctx: TickContext, post: Posterior, status: str, detail: str
          ) -> tuple[float, float, bool, str, str]:
    """The published ``moisture_out``, its standard deviation, whether it is the lab-anchored
    fallback, and status and detail after the guard (module docstring)."""
    jitter = filt.settings.moisture_out_jitter_std
    mo = float(post.y_mean[_MO])
    mo_std = math.sqrt(max(post.y_var[_MO], 0.0) + jitter**2) if math.isfinite(mo) else math.nan
    is_fallback = False
    why = "" if ctx.window.stale else lost(filt, post)
    if why or not math.isfinite(mo):
        anchor = fallback(filt, ctx)
        if anchor is not None:
            mo, mo_std, sid = anchor
            is_fallback = True
            status = "degraded"
            detail = (f"model lost the plant ({why or 'no model estimate'}): moisture_out "
                      f"is the last lab result {sid} {mo:.4f} +- {mo_std:.4f} kg/kg; " + detail)
        elif why:
            status = "degraded"
            detail = f"model lost the plant ({why}); no lab result yet; " + detail
    bad_sensor = "" if ctx.window.stale else suspect(filt, post.x)
    if bad_sensor:
        status = "degraded"
        detail = f"{bad_sensor}; {detail}"
    return mo, mo_std, is_fallback, status, detail


def publish(filt: FilterModel, ctx: TickContext, post: Posterior, kind: str) -> dict[str, Any]:
    """The estimate body of one tick (``lab_updated`` and ``notes`` are set by the
    estimator)."""
    s = filt.settings
    status, detail = health(filt, ctx, post)
    mo, mo_std, is_fallback, status, detail = guard(filt, ctx, post, status, detail)
    clipped = math.isfinite(mo) and not s.moisture_out_min <= mo <= s.moisture_out_max
    if clipped:
        mo = min(max(mo, s.moisture_out_min), s.moisture_out_max)
    x, P = post.x, post.P
    x_in, x_in_std = inlet_moments(filt, x, P)
    inn = post.innovation
    return {
        "moisture_out": finite_or_none(mo),
        "moisture_out_std": finite_or_none(mo_std),
        "moisture_out_window_std": finite_or_none(math.sqrt(max(post.y_var[_MO], 0.0))),
        "moisture_in": x_in,
        "moisture_in_std": x_in_std,
        "moisture_out_bias": float(x[X_BIAS]),
        "moisture_out_bias_std": float(math.sqrt(P[X_BIAS, X_BIAS])),
        "inlet_gain": float(x[X_GAIN]),
        "T_air_in_offset": float(x[X_HEAT]),
        "T_offset": float(filt.heat_gain * x[X_HEAT]),
        "T_dryer_out_offset": float(x[X_TDRY]),
        "T_cyclone_out_offset": float(x[X_TCYC]),
        "T_dryer_out_model": finite_or_none(post.y_mean[0]),
        "T_cyclone_out_model": finite_or_none(post.y_mean[1]),
        "T_dryer_out_model_raw": finite_or_none(float(post.model_T[0])),
        "T_cyclone_out_model_raw": finite_or_none(float(post.model_T[1])),
        "fallback": is_fallback,
        "clipped": clipped,
        "nis": inn.nis if inn.dof else None,
        "nis_dof": inn.dof,
        "labs_applied": [r.sample_id for r in ctx.labs],
        "lab_updated": bool(ctx.labs),
        "status": status,
        "detail": detail,
        "discrepancy_priors": filt.priors.source,
        "window_start_ns": int(ctx.window.start_ns),
        "window_end_ns": int(ctx.window.end_ns),
        "estimator": kind,
    }


__all__ = ["TickContext", "fallback", "guard", "health", "lost", "publish", "suspect"]
