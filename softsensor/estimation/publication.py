"""From a tick's posterior to the filter's :class:`~softsensor.estimate.Estimate`: the one
place the filter's estimate is built (the open-loop estimator builds its own, simpler one).

:func:`physics` is handed the posterior of :func:`~.ukf_step.step` and what it needs of the
history (:class:`TickContext`: the tick's window and labs, the innovations of the previous
ticks, the latest lab result applied so far) and returns the filter's estimate with its
reasons; :func:`blended` puts the peers' blend (:mod:`.peer_blend`) on it; :func:`at_tick`
adds what only the tick knows (a late lab applied, the notes of the ticks filtered again, a
streak of refused lab results). The service finishes any estimator's estimate by one pure step
(:func:`softsensor.service.estimator_service.finish`).

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
from dataclasses import dataclass, replace

import numpy as np

from softsensor.estimate import Blend, Estimate, FilterTerms, Reason
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


def verdict(filt: FilterModel, ctx: TickContext, post: Posterior) -> Reason:
    """The tick's verdict before the guard: stale, degraded by a failed model, or the
    chi-square test of the last ``consistency_ticks`` innovations."""
    w = ctx.window
    if w.stale:
        reasons = "; ".join(f"{key}: {v}" for key, v in w.reasons.items())
        return Reason("stale", "stale window, predicting without correction" + (
            f": {reasons}" if reasons else ""))
    if post.failure:
        return Reason("degraded", post.failure)
    test = chi_square_test([*ctx.recent, post.innovation], filt.settings.consistency_alpha)
    detail = test.detail
    if ctx.held:
        detail += f"; holding last value of {', '.join(ctx.held)}"
    return Reason(test.status, detail)


@dataclass(frozen=True)
class Guarded:
    """The physics' published outlet moisture after the guard: value and band sd [kg/kg],
    whether it is the lab-anchored fallback, and the guard's reasons (first first)."""

    moisture_out: float
    moisture_out_std: float
    fallback: bool
    reasons: tuple[Reason, ...]


def guard(filt: FilterModel, ctx: TickContext, post: Posterior) -> Guarded:
    """The published ``moisture_out``, its standard deviation, whether it is the lab-anchored
    fallback, and what the guard says (module docstring)."""
    jitter = filt.settings.moisture_out_jitter_std
    mo = float(post.y_mean[_MO])
    mo_std = math.sqrt(max(post.y_var[_MO], 0.0) + jitter**2) if math.isfinite(mo) else math.nan
    is_fallback = False
    reasons = []
    why = "" if ctx.window.stale else lost(filt, post)
    if why or not math.isfinite(mo):
        anchor = fallback(filt, ctx)
        if anchor is not None:
            mo, mo_std, sid = anchor
            is_fallback = True
            reasons.append(Reason("degraded", f"model lost the plant ({why or 'no model estimate'}"
                                              f"): moisture_out is the last lab result {sid} "
                                              f"{mo:.4f} +- {mo_std:.4f} kg/kg"))
        elif why:
            reasons.append(Reason("degraded", f"model lost the plant ({why}); no lab result yet"))
    bad_sensor = "" if ctx.window.stale else suspect(filt, post.x)
    if bad_sensor:
        reasons.insert(0, Reason("degraded", bad_sensor))
    return Guarded(mo, mo_std, is_fallback, tuple(reasons))


def physics(filt: FilterModel, ctx: TickContext, post: Posterior, kind: str) -> Estimate:
    """The filter's estimate of one tick: the posterior's outputs after the guard, its
    states, and its reasons (the guard's, then the verdict)."""
    s = filt.settings
    g = guard(filt, ctx, post)
    mo = g.moisture_out
    clipped = math.isfinite(mo) and not s.moisture_out_min <= mo <= s.moisture_out_max
    if clipped:
        mo = min(max(mo, s.moisture_out_min), s.moisture_out_max)
    x, P = post.x, post.P
    x_in, x_in_std = inlet_moments(filt, x, P)
    inn = post.innovation
    terms = FilterTerms(
        moisture_out_window_std=finite_or_none(math.sqrt(max(post.y_var[_MO], 0.0))),
        moisture_out_bias=finite_or_none(x[X_BIAS]),
        moisture_out_bias_std=finite_or_none(math.sqrt(P[X_BIAS, X_BIAS])),
        inlet_gain=finite_or_none(x[X_GAIN]), T_air_in_offset=finite_or_none(x[X_HEAT]),
        T_offset=finite_or_none(filt.heat_gain * x[X_HEAT]),
        T_dryer_out_offset=finite_or_none(x[X_TDRY]),
        T_cyclone_out_offset=finite_or_none(x[X_TCYC]),
        T_dryer_out_model_raw=finite_or_none(float(post.model_T[0])),
        T_cyclone_out_model_raw=finite_or_none(float(post.model_T[1])),
        nis=inn.nis if inn.dof else None, nis_dof=inn.dof, fallback=g.fallback,
        labs_applied=tuple(r.sample_id for r in ctx.labs),
        discrepancy_priors=filt.priors.source)
    return Estimate(
        window_start_ns=int(ctx.window.start_ns), window_end_ns=int(ctx.window.end_ns),
        estimator=kind, moisture_out=finite_or_none(mo),
        moisture_out_std=finite_or_none(g.moisture_out_std),
        moisture_in=finite_or_none(x_in), moisture_in_std=finite_or_none(x_in_std),
        T_dryer_out_model=finite_or_none(post.y_mean[0]),
        T_cyclone_out_model=finite_or_none(post.y_mean[1]),
        lab_updated=bool(ctx.labs), reasons=(*g.reasons, verdict(filt, ctx, post)),
        clipped=clipped, notes=tuple(post.notes), filter=terms)


def blended(estimate: Estimate, blend: Blend, mixture: tuple[float, float] | None,
            s: EstimatorSettings) -> Estimate:
    """``estimate`` published as the peers' ``mixture`` (mean and band sd [kg/kg], None when
    no source has a weight), clipped to its range, with the ``blend`` it came from; when a
    peer leads, the reason why first."""
    out = replace(estimate, blend=blend)
    if mixture is not None:
        mean, band = mixture
        clipped = not s.moisture_out_min <= mean <= s.moisture_out_max
        out = replace(out, moisture_out=min(max(mean, s.moisture_out_min), s.moisture_out_max),
                      moisture_out_std=band, clipped=estimate.clipped or clipped)
    if blend.source != "physics":
        weights = ", ".join(f"{n} {src.weight:.2f}" for n, src in blend.sources.items())
        out = out.judged(Reason("ok", f"the lab results favour {blend.source} over the physics "
                                      f"(weights {weights})"), first=True)
    return out


def at_tick(estimate: Estimate, *, lab_updated: bool, notes: tuple[str, ...],
            refused_streak: int) -> Estimate:
    """The estimate a tick publishes: a lab result applied late counts as an update, the
    notes of the ticks filtered again come first, and a streak of two or more lab results
    refused on one side (``refused_streak``, signed by the side) degrades it: the labs and
    the sensor disagree, which is never said silently."""
    out = replace(estimate, lab_updated=estimate.lab_updated or lab_updated,
                  notes=(*notes, *estimate.notes))
    if abs(refused_streak) >= 2:
        side = "above" if refused_streak > 0 else "below"
        out = out.judged(Reason("degraded", f"{abs(refused_streak)} lab results in a row "
                                            f"refused {side} the estimate (the lab or the "
                                            f"model is off)"), first=True)
    return out


__all__ = ["Guarded", "TickContext", "at_tick", "blended", "fallback", "fallback_std", "guard",
           "lost", "physics", "suspect", "verdict"]
