"""The peers inside the sensor and the band that holds: what is published, from which source.

The filter's physics (:mod:`.ukf`) can be misled: an effect it cannot follow, parameters that
are off. A plant keeps two simpler estimates that cannot be misled that way, and this module
runs them beside the physics:

* **hold**: the latest lab result (by sample time), its band the lab-anchored fallback's
  (:func:`.publication.fallback`: lab noise, jitter and a drift growing with the hours since);
* **regression**: the lab regression fitted on the same history as the calibration
  (PARAMS.toml's ``[regression]``, :mod:`.lab_regression`) at the window's signal means, plus
  the lab bias of the latest result; its spread the history's next-lab error (``step_sd``).
  Without a ``[regression]`` only the hold runs beside the physics.

**Weighing by evidence** (dynamic model averaging: Raftery, Kárný and Ettler, Technometrics
52, 2010). Each lab result, before it is used, is scored by each source's predictive density:
the physics' estimate at the previous tick with its band and the lab noise, the hold's and the
regression's as they stood. The log weights are first flattened towards the prior
(``log w <- a log w + (1 - a) log prior``, ``a = estimator.peer_forgetting`` per lab result:
old evidence fades, so a source that was wrong yesterday can win today), then the log
likelihood is added and they are normalised. The prior (``estimator.peer_prior_physics`` on
the physics, the rest shared by the peers) is where the weights return without labs. The
published ``moisture_out`` is the weighted mean of the sources, its variance the mixture's
(each source's band plus the spread of the sources about the mean): on a day where the labs
keep contradicting the physics the estimate moves to the peer they agree with, by the lab
likelihood and no threshold; on a clean day the physics keeps its weight.

**A band that holds** (adaptive conformal inference: Gibbs and Candès, NeurIPS 2021; on a scale
as in Angelopoulos, Candès and Tibshirani's quantile tracking, 2023). The published standard
deviation is the mixture's times a scale ``c``. At each lab result, before it is used: a miss
is the result outside ``mean +- 1.96 sqrt((c band)^2 + lab_std^2)``, and ``log c`` moves by
``estimator.band_step * (miss - 0.05)``, within ``[band_scale_min, band_scale_max]``: a miss
widens by ``exp(0.95 step)``, a hit narrows by ``exp(-0.05 step)``, so the share of misses is
driven to 5 %, whatever the filter believes of itself.

The state (log weights, ``log c``, the latest lab, the regression's bias, the physics' last
estimate) travels in :class:`~.tick_history.FilterState` (``peers``), so a late lab result
re-filters it with the history and a checkpoint restores it. Pure: no clock, no log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from softsensor.estimate import Blend, SourceEstimate
from softsensor.estimation.interface import LabResult, Window
from softsensor.estimation.lab_regression import LabRegression
from softsensor.estimation.publication import fallback_std
from softsensor.estimation.settings import EstimatorSettings

#: The sources, in the order of the weights.
SOURCES: tuple[str, ...] = ("physics", "hold", "regression")
_Z95 = 1.96
_MISS = 0.05
#: Lowest log weight kept (a source a hundred nats behind can still come back within a few
#: lab results once the forgetting has flattened it).
_LOG_FLOOR = -100.0


@dataclass(frozen=True)
class Source:
    """One source's estimate: the published value and band sd (truth), and the predictive sd
    of a lab result (band plus what the lab adds)."""

    value: float
    band: float
    predictive: float

    @property
    def ok(self) -> bool:
        return math.isfinite(self.value) and math.isfinite(self.band) and self.predictive > 0


def prior_log_weights(s: EstimatorSettings, reg: LabRegression | None) -> np.ndarray:
    """Log prior weights of :data:`SOURCES`: ``peer_prior_physics`` on the physics,
    ``peer_prior_hold`` on the hold (None: the peers share the rest), the rest on the
    regression (at a finite nothing, -690, without a fit: the state stays JSON)."""
    rest = 1.0 - s.peer_prior_physics
    if reg is None:
        p = np.array([s.peer_prior_physics, rest, 0.0])
    elif s.peer_prior_hold is None:
        p = np.array([s.peer_prior_physics, rest / 2, rest / 2])
    else:
        hold = min(s.peer_prior_hold, rest)
        p = np.array([s.peer_prior_physics, hold, rest - hold])
    return np.log(np.maximum(p, 1e-300))


def fresh(s: EstimatorSettings, reg: LabRegression | None) -> dict[str, Any]:
    """The state before any tick (JSON)."""
    return {"log_w": [float(v) for v in prior_log_weights(s, reg)], "log_scale": 0.0,
            "hold": None, "bias": None, "physics": None, "labs": 0, "misses": 0,
            "msz": [1.0] * len(SOURCES)}


def check_state(state: dict[str, Any]) -> None:
    """ValueError (or KeyError, TypeError) unless ``state`` is empty or a state of
    :func:`advance` (a checkpoint is read like any other input)."""
    if not state:
        return
    log_w = np.array(state["log_w"], float)
    if log_w.shape != (len(SOURCES),) or np.any(np.isnan(log_w)) or np.any(log_w > 0):
        raise ValueError(f"peers.log_w must be {len(SOURCES)} log weights, got {log_w}")
    if not math.isfinite(float(state["log_scale"])):
        raise ValueError("peers.log_scale must be finite")
    for key in ("hold", "physics"):
        v = state[key]
        if v is not None and (len(v) != 2 or not all(math.isfinite(float(x)) for x in v)):
            raise ValueError(f"peers.{key} must be null or two finite numbers")
    msz = np.array(state["msz"], float)
    if msz.shape != (len(SOURCES),) or not np.all(np.isfinite(msz)) or np.any(msz < 0):
        raise ValueError(f"peers.msz must be {len(SOURCES)} finite numbers >= 0, got {msz}")
    if state["bias"] is not None and not math.isfinite(float(state["bias"])):
        raise ValueError("peers.bias must be null or finite")
    int(state["labs"]), int(state["misses"])


def _normalised(log_w: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Weights over the sources that are ``ok`` (zero elsewhere)."""
    w = np.zeros(len(log_w))
    lw = np.where(ok, log_w, -np.inf)
    if not np.any(np.isfinite(lw)):
        return w
    top = np.max(lw[np.isfinite(lw)])
    e = np.where(np.isfinite(lw), np.exp(lw - top), 0.0)
    return e / e.sum()


def _mixture(sources: list[Source], w: np.ndarray) -> tuple[float, float]:
    """Mean and band sd of the mixture of ``sources`` weighted ``w`` (zero weights skipped)."""
    used = [(wi, src) for wi, src in zip(w, sources, strict=True) if wi > 0]
    mean = sum(wi * src.value for wi, src in used)
    var = sum(wi * (src.band**2 + (src.value - mean) ** 2) for wi, src in used)
    return float(mean), math.sqrt(var)


def _hold_source(s: EstimatorSettings, value: float | None, sample_ns: int | None,
                 at_ns: int) -> Source:
    """The hold: the lab-anchored fallback's band (:func:`.publication.fallback_std`)."""
    if value is None or sample_ns is None:
        return Source(math.nan, math.nan, 0.0)
    band = fallback_std(s, at_ns - sample_ns)
    return Source(value, band, math.sqrt(band**2 + s.lab_std**2))


def _regression_source(s: EstimatorSettings, reg: LabRegression | None, bias: float | None,
                       at_window: float) -> Source:
    """The regression at the window's means (``at_window``) plus the lab bias."""
    if reg is None or bias is None:
        return Source(math.nan, math.nan, 0.0)
    # the history's next-lab error holds the lab noise of the result predicted; the band of
    # the truth leaves it out
    band = math.sqrt(max(reg.step_sd**2 - s.lab_std**2, s.lab_std**2))
    return Source(at_window + bias, band, reg.step_sd)


def _physics_source(s: EstimatorSettings, est: list[float] | None) -> Source:
    if est is None:
        return Source(math.nan, math.nan, 0.0)
    mean, band = est
    return Source(mean, band, math.sqrt(band**2 + s.lab_std**2))


def _log_density(x: float, src: Source, spread: float = 1.0) -> float:
    """Log density of ``x`` under ``src``'s predictive Gaussian, its sd times ``spread``."""
    sd = src.predictive * spread
    z = (x - src.value) / sd
    return -0.5 * z * z - math.log(sd) - 0.5 * math.log(2 * math.pi)


def advance(s: EstimatorSettings, reg: LabRegression | None, state: dict[str, Any],
            window: Window, labs: tuple[LabResult, ...],
            physics: tuple[float | None, float | None]
            ) -> tuple[dict[str, Any], Blend, tuple[float, float] | None]:
    """One tick: score ``labs`` (sampled in ``window``) against each source as it stood,
    update the weights and the band's scale, then blend the sources with ``physics`` (the
    filter's published estimate and band sd, its guard applied). Returns the new state, the
    :class:`~softsensor.estimate.Blend`, and the blend's mean and band sd (None when no source
    has a weight) [kg/kg]."""
    st = dict(state)
    # the window is the same for every lab of the tick: the regression read once
    reg_now = math.nan if reg is None else reg.at_means(window.means)
    scored = _Scores(np.array(st["log_w"], float), float(st["log_scale"]),
                     np.array(st["msz"], float))
    phys_prev = _physics_source(s, st["physics"])
    prior = prior_log_weights(s, reg)
    for lab in sorted(labs, key=lambda r: (r.sample_time_ns, r.sample_id)):
        _score(s, reg, prior, st, scored, lab, phys_prev, reg_now)
    st["log_w"] = [float(v) for v in scored.log_w]
    st["log_scale"] = scored.log_c
    st["msz"] = [float(v) for v in scored.msz]
    mo, mo_std = physics
    st["physics"] = (None if mo is None or mo_std is None else [float(mo), float(mo_std)])
    hold = st["hold"]
    sources = [_physics_source(s, st["physics"]),
               _hold_source(s, None if hold is None else hold[0],
                            None if hold is None else hold[1], window.end_ns),
               _regression_source(s, reg, st["bias"], reg_now)]
    ok = np.array([src.ok for src in sources])
    w = (_normalised(scored.log_w, ok) if s.peer_blend
         else np.array([1.0 if sources[0].ok else 0.0, 0.0, 0.0]))
    mixture = None
    if w.sum() > 0:
        mean, band = _mixture(sources, w)
        mixture = (mean, band * math.exp(scored.log_c))
    blend = Blend(
        moisture_out_physics=mo, moisture_out_physics_std=mo_std,
        sources=MappingProxyType({name: SourceEstimate(
            float(wi), src.value if math.isfinite(src.value) else None,
            src.band if math.isfinite(src.band) else None)
            for name, wi, src in zip(SOURCES, w, sources, strict=True)}),
        band_scale=math.exp(scored.log_c), band_misses=(int(st["misses"]), int(st["labs"])),
        source=SOURCES[int(np.argmax(w))] if w.sum() > 0 else "physics")
    return st, blend, mixture


@dataclass
class _Scores:
    """The evidence a tick's lab results move: log weights, the band's log scale and each
    source's mean squared z (its spread as the recent labs found it)."""

    log_w: np.ndarray
    log_c: float
    msz: np.ndarray


def _score(s: EstimatorSettings, reg: LabRegression | None, prior: np.ndarray,
           st: dict[str, Any], scored: _Scores, lab: LabResult, phys_prev: Source,
           reg_now: float) -> None:
    """Score one lab result against each source as it stood (module docstring): forget
    towards the prior, add its log likelihood, move the band's scale; then it becomes the
    hold and sets the regression's bias. Updates ``st`` and ``scored`` in place."""
    hold = st["hold"]
    sources = [phys_prev,
               _hold_source(s, None if hold is None else hold[0],
                            None if hold is None else hold[1], lab.sample_time_ns),
               _regression_source(s, reg, st["bias"], reg_now)]
    ok = np.array([src.ok for src in sources])
    log_w = s.peer_forgetting * scored.log_w + (1.0 - s.peer_forgetting) * prior
    if s.peer_blend and ok.sum() >= 2:  # evidence needs two sources to compare
        w_pred = _normalised(log_w, ok)
        z2 = np.array([((lab.moisture_out - src.value) / src.predictive) ** 2 if src.ok
                       else 1.0 for src in sources])
        # each source scored with its spread as the recent labs found it (never narrower
        # than it says itself): a band too narrow is not evidence against an estimate
        # nearer the labs than a wider one
        spread = np.sqrt(np.maximum(scored.msz, 1.0))
        ll = np.array([_log_density(lab.moisture_out, src, k) if src.ok else 0.0
                       for src, k in zip(sources, spread, strict=True)])
        # tempered (``peer_evidence``): 0 keeps the learned stacking weights of the prior
        log_w = log_w + s.peer_evidence * np.where(ok, ll, 0.0)
        log_w = np.maximum(log_w - np.max(log_w), _LOG_FLOOR)
        scored.msz = np.where(ok, s.peer_forgetting * scored.msz
                              + (1.0 - s.peer_forgetting) * z2, scored.msz)
    else:
        w_pred = np.array([1.0, 0.0, 0.0]) if sources[0].ok else _normalised(log_w, ok)
    scored.log_w = log_w
    if s.band_conformal and ok.any():
        mean, band = _mixture(sources, w_pred)
        half = _Z95 * math.sqrt((math.exp(scored.log_c) * band) ** 2 + s.lab_std**2)
        miss = abs(lab.moisture_out - mean) > half
        scored.log_c = min(max(scored.log_c + s.band_step * (float(miss) - _MISS),
                               math.log(s.band_scale_min)), math.log(s.band_scale_max))
        st["misses"] = int(st["misses"]) + int(miss)
    st["labs"] = int(st["labs"]) + 1
    if hold is None or lab.sample_time_ns >= hold[1]:
        st["hold"] = [float(lab.moisture_out), int(lab.sample_time_ns)]
    if reg is not None:
        st["bias"] = float(lab.moisture_out - reg_now)


__all__ = ["SOURCES", "Source", "advance", "check_state", "fresh", "prior_log_weights"]
