"""The advice of one tick, or the one-line reason why there is none:
:func:`~softsensor.advisor.advice.advise`.

:func:`advise` is handed what the sensor knows now (:class:`Situation`: the window's inputs
and set point, the published estimate and its band, the health, the recent production and
set point) and the calibrated model with its parameters' covariance, and returns an
:class:`Advice`. The refusals come first, each one line:

1. the health is not ``ok`` (the estimate or its band cannot be trusted);
2. no estimate, or no band;
3. a production change or a set-point move within ``steady_window`` (the plant is moving;
   a steady-state advice would aim at a point it has not reached);
4. the operating point now outside the envelope the history covers (:class:`Envelope`);
5. the model cannot be solved at the point, or the set point that holds the target lies
   beyond the envelope or the largest move;
6. the band at that set point wider than the margin it would spend: ``z sd`` above
   ``moisture_max - moisture_target``, so the target could not be held with the confidence
   asked.

Otherwise the advised set point is the lowest (least heat) within reach whose predicted
outlet moisture is at most the target and whose upper ``confidence`` quantile is within
``moisture_max``: the target itself, or the lowest set point within reach when even that
keeps the moisture below the target (``limited_by`` says which bound). Advisory only:
nothing here or anywhere in the package writes a set point to the PLC.

No I/O here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from statistics import NormalDist
from typing import Any

import numpy as np

from softsensor.advisor.search import (
    SP_RESOLUTION,
    curves,
    heat_duty,
    per_tonne,
    predict,
    settling_time,
)
from softsensor.advisor.settings import AdvisorSettings
from softsensor.errors import ConfigError, SolverError
from softsensor.estimation.model_error import ModelError
from softsensor.model import DryerModel
from softsensor.signals import INPUT_NAMES, SCAN_SIGNALS

_TA = INPUT_NAMES.index("T_air_in")

#: Units of the envelope's features, for the refusal's sentence.
_UNIT = SCAN_SIGNALS


@dataclass(frozen=True)
class Envelope:
    """The operating envelope the calibration history covers: per feature of its
    ``[model_error]`` (window means over the history) the mean plus or minus ``k`` history
    standard deviations. [SI units of each feature]"""

    low: Mapping[str, float]
    high: Mapping[str, float]

    @classmethod
    def of(cls, me: ModelError, k: float) -> Envelope:
        """The envelope of a ``[model_error]``; it must bound ``T_air_in`` and ``T_sp``."""
        for name in ("T_air_in", "T_sp"):
            if name not in me.features:
                raise ConfigError(f"[model_error].features has no {name}: the advisor needs "
                                  "the history's range of it")
        return cls({n: m - k * s for n, m, s in zip(me.features, me.mean, me.scale, strict=True)},
                   {n: m + k * s for n, m, s in zip(me.features, me.mean, me.scale, strict=True)})

    def range(self, name: str) -> tuple[float, float]:
        """The envelope of ``name`` (infinite when the history does not bound it)."""
        return self.low.get(name, -math.inf), self.high.get(name, math.inf)

    def outside(self, values: Mapping[str, float]) -> str:
        """The first value outside the envelope, in words ('' when none is)."""
        for name, v in values.items():
            lo, hi = self.range(name)
            if math.isfinite(v) and not lo <= v <= hi:
                return (f"{name} {v:.4g} {_UNIT.get(name, '')} is outside the envelope the "
                        f"history covers ({lo:.4g} to {hi:.4g})")
        return ""


@dataclass(frozen=True)
class Situation:
    """What the sensor knows at one tick.

    Attributes
    ----------
    time_ns : int
        End of the window. [ns]
    inputs : Mapping[str, float]
        The window's mean of each scan signal (``T_air_in``, ``m_air``, ..., ``T_sp``,
        ``T_dryer_out``). [SI]
    moisture_in : float or None
        The estimate's inlet moisture. [kg/kg]
    moisture_out, moisture_out_std : float or None
        The published outlet moisture and its band's standard deviation. [kg/kg]
    health, health_detail : str
        The health's status and detail at the tick.
    recent_m_fiber, recent_T_sp : sequence of float
        Window means of ``m_fiber`` [kg/s] and ``T_sp`` [K] over the last ``steady_window``.
    """

    time_ns: int
    inputs: Mapping[str, float]
    moisture_in: float | None
    moisture_out: float | None
    moisture_out_std: float | None
    health: str
    health_detail: str
    recent_m_fiber: Sequence[float]
    recent_T_sp: Sequence[float]

    def model_inputs(self) -> np.ndarray:
        """The model's input vector (8,): the window's means, the estimated inlet moisture."""
        vals = {**self.inputs, "moisture_in": self.moisture_in}
        return np.array([float(vals[n]) for n in INPUT_NAMES])


@dataclass(frozen=True)
class Advice:
    """One tick's advice (``advised`` true) or refusal (``reason`` says why, one line).

    Numbers that a refusal leaves unknown are None. Units: K, kg/kg, kW, kWh/t, s.
    """

    time_ns: int
    advised: bool
    reason: str
    T_sp: float | None = None
    T_sp_advised: float | None = None
    T_air_in: float | None = None
    T_air_in_advised: float | None = None
    moisture_out: float | None = None
    moisture_out_std: float | None = None
    moisture_out_advised: float | None = None
    moisture_out_advised_std: float | None = None
    moisture_out_change_std: float | None = None
    p_within_max: float | None = None
    duty_kw: float | None = None
    duty_advised_kw: float | None = None
    duty_kwh_per_t: float | None = None
    duty_advised_kwh_per_t: float | None = None
    saving_kwh_per_t: float | None = None
    settle_s: float | None = None
    limited_by: str | None = None
    moisture_target: float | None = None
    moisture_max: float | None = None
    confidence: float | None = None

    def to_body(self) -> dict[str, Any]:
        """The JSON body published on ``softsensor/<unit>/advice`` (docs/interface.md)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                v = None
            out[f.name] = v
        return out

    @classmethod
    def from_body(cls, b: Mapping[str, Any]) -> Advice:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in b.items() if k in names})


def _refused(s: Situation, why: str, cfg: AdvisorSettings, **known: Any) -> Advice:
    return Advice(s.time_ns, False, why, moisture_target=cfg.moisture_target,
                  moisture_max=cfg.moisture_max, confidence=cfg.confidence, **known)


def precheck(s: Situation, cfg: AdvisorSettings, env: Envelope) -> str:
    """Why no advice can be given at ``s`` before the model is asked ('' when none)."""
    if s.health != "ok":
        first = s.health_detail.split("; ")[0]
        return f"health is {s.health}: {first if len(first) <= 160 else first[:157] + '...'}"
    if s.moisture_out is None or s.moisture_in is None:
        return "no estimate of the outlet or inlet moisture this tick"
    if s.moisture_out_std is None or not s.moisture_out_std > 0:
        return "the estimate has no band"
    missing = [n for n in INPUT_NAMES[:-1] + ("T_sp", "T_dryer_out")
               if not math.isfinite(float(s.inputs.get(n, math.nan)))]
    if missing:
        return f"no reading of {missing[0]} this window"
    mf = np.asarray(s.recent_m_fiber, float)
    mf = mf[np.isfinite(mf)]
    minutes = cfg.steady_window / 60
    if mf.size and (mf.max() - mf.min()) / mf.mean() > cfg.production_change:
        return (f"production change: the dry-fibre flow moved {mf.min():.2f} to "
                f"{mf.max():.2f} kg/s in the last {minutes:.0f} min")
    sp = np.asarray(s.recent_T_sp, float)
    sp = sp[np.isfinite(sp)]
    if sp.size and sp.max() - sp.min() > cfg.setpoint_change:
        return (f"the set point moved {sp.max() - sp.min():.1f} K in the last {minutes:.0f} "
                "min: the plant has not settled")
    return env.outside(s.inputs)


def advise(model: DryerModel, theta: np.ndarray, cov: np.ndarray, s: Situation,
           cfg: AdvisorSettings, env: Envelope) -> Advice:
    """The advice at ``s`` (module docstring): ``theta`` the calibrated parameters (7,),
    ``cov`` their covariance in ln(theta) (7, 7)."""
    why = precheck(s, cfg, env)
    if why:
        return _refused(s, why, cfg)
    u = s.model_inputs()
    T_sp, T_out = float(s.inputs["T_sp"]), float(s.inputs["T_dryer_out"])
    now = dict(T_sp=T_sp, T_air_in=float(u[_TA]), moisture_out=s.moisture_out,
               moisture_out_std=s.moisture_out_std)
    ta_lo, ta_hi = env.range("T_air_in")
    sp_lo, sp_hi = env.range("T_sp")
    lo_bound = "envelope" if sp_lo >= T_sp - cfg.max_step else "max_step"
    hi_bound = "envelope" if sp_hi <= T_sp + cfg.max_step else "max_step"
    sp_lo, sp_hi = max(sp_lo, T_sp - cfg.max_step), min(sp_hi, T_sp + cfg.max_step)
    if not sp_hi > sp_lo:
        return _refused(s, f"the set point {T_sp:.2f} K leaves no room within the envelope",
                        cfg, **now)
    try:
        c = curves(model, u, theta, ta_lo, ta_hi, T_out, sp_lo, sp_hi)
    except SolverError as exc:
        return _refused(s, f"the model cannot be solved here: {exc}", cfg, **now)
    grid = np.arange(sp_lo, sp_hi + SP_RESOLUTION / 2, SP_RESOLUTION)
    p = predict(c, cov, grid, T_out, float(s.moisture_out), float(s.moisture_out_std))
    reach = np.isfinite(p.mean)
    if not reach.any():
        return _refused(s, "no set point within the envelope the history covers is reached "
                           "within its T_air_in range", cfg, **now)
    meets = reach & (p.mean <= cfg.moisture_target)
    if not meets.any():
        top = float(grid[reach][-1])
        bound = hi_bound if top >= sp_hi - 1.5 * SP_RESOLUTION else "T_air_in envelope"
        return _refused(s, f"holding {cfg.moisture_target:.3f} kg/kg needs a set point above "
                           f"{top:.1f} K, beyond the {bound} (predicted "
                           f"{p.mean[reach][-1]:.3f} kg/kg there)", cfg, **now)
    i = int(np.flatnonzero(meets)[0])
    z = NormalDist().inv_cdf(cfg.confidence)
    margin = cfg.moisture_max - cfg.moisture_target
    if z * p.std[i] > margin:
        return _refused(s, f"the band at {cfg.confidence:.0%} (+-{z * p.std[i]:.3f} kg/kg) is "
                           f"wider than the margin it would spend ({margin:.3f} kg/kg from "
                           f"target to limit)", cfg, **now)
    limited = None
    if i == 0 and p.mean[0] < cfg.moisture_target - 1e-4:
        limited = lo_bound if reach[0] else "T_air_in envelope"
    u_adv = u.copy()
    u_adv[_TA] = p.T_air_in[i]
    q_now, q_adv = heat_duty(u), heat_duty(u_adv)
    mf = float(s.inputs["m_fiber"])
    try:
        settle = settling_time(model, u, u_adv, theta, cfg.settle_fraction, cfg.settle_horizon)
    except SolverError as exc:
        return _refused(s, f"the model cannot be solved on the way there: {exc}", cfg, **now)
    p_within = NormalDist(float(p.mean[i]), float(p.std[i])).cdf(cfg.moisture_max)
    return Advice(
        s.time_ns, True, _sentence(T_sp, float(grid[i]), float(p.mean[i]), z * float(p.std[i]),
                                   per_tonne(q_now - q_adv, mf), settle, limited),
        T_sp=T_sp, T_sp_advised=float(grid[i]), T_air_in=float(u[_TA]),
        T_air_in_advised=float(p.T_air_in[i]), moisture_out=s.moisture_out,
        moisture_out_std=s.moisture_out_std, moisture_out_advised=float(p.mean[i]),
        moisture_out_advised_std=float(p.std[i]),
        moisture_out_change_std=float(p.change_std[i]), p_within_max=p_within,
        duty_kw=q_now / 1e3, duty_advised_kw=q_adv / 1e3, duty_kwh_per_t=per_tonne(q_now, mf),
        duty_advised_kwh_per_t=per_tonne(q_adv, mf),
        saving_kwh_per_t=per_tonne(q_now - q_adv, mf), settle_s=settle, limited_by=limited,
        moisture_target=cfg.moisture_target, moisture_max=cfg.moisture_max,
        confidence=cfg.confidence)


def _sentence(T_sp: float, T_adv: float, m: float, half: float, saving: float,
              settle: float | None, limited: str | None) -> str:
    settle_txt = "more than the horizon" if settle is None else f"{settle / 60:.0f} min"
    lim = f"; limited by the {limited}" if limited else ""
    return (f"T_sp {T_sp:.1f} -> {T_adv:.1f} K: outlet moisture {m:.3f} +- {half:.3f} kg/kg, "
            f"{saving:+.1f} kWh/t saved, settles in {settle_txt}{lim}")


__all__ = ["Advice", "Envelope", "Situation", "advise", "precheck"]
