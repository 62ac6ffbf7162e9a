"""The what-if over recorded estimates: the advice hour by hour and what following it would
have changed.

A recording of the streaming path (``softsensor replay``, or the daemon's) holds the scans,
the estimates and the health. :func:`situations` turns it into one :class:`Situation` per
``every`` seconds (the first estimate tick at or after each boundary: hourly by default),
with the window's scan means, the estimate, the health then in force, and the window means
of ``m_fiber`` and ``T_sp`` over the last ``steady_window``. :func:`what_if` sums what the
advice would have done: the heat saved against the set point as run [kWh and kWh/t], the
hours advised and refused (by reason), and the expected hours above ``moisture_max``
following the advice (the sum of each advised hour's probability of exceeding it) beside the
hours the estimate put above it as run.

No I/O here: the caller reads the recording.
"""

from __future__ import annotations

import bisect
import math
import re
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from softsensor.advisor.advice import Advice, Situation
from softsensor.advisor.settings import AdvisorSettings
from softsensor.signals import SCAN_SIGNALS


def _window_means(scans: pd.DataFrame, start_ns: np.ndarray, end_ns: np.ndarray
                  ) -> np.ndarray:
    """Mean of each scan signal over each ``[start, end)`` (NaN where no scan), (N, S)."""
    t = scans.index.to_numpy(np.int64)
    vals = scans.reindex(columns=list(SCAN_SIGNALS)).to_numpy(float)
    ok = np.isfinite(vals)
    csum = np.vstack([np.zeros(vals.shape[1]), np.cumsum(np.where(ok, vals, 0.0), axis=0)])
    ccnt = np.vstack([np.zeros(vals.shape[1]), np.cumsum(ok, axis=0)])
    a = np.searchsorted(t, start_ns, side="left")
    b = np.searchsorted(t, end_ns, side="left")
    n = ccnt[b] - ccnt[a]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (csum[b] - csum[a]) / np.maximum(n, 1), np.nan)


def situations(scans: pd.DataFrame, estimates: Sequence[tuple[int, Mapping[str, Any]]],
               health: Sequence[tuple[int, Mapping[str, Any]]], cfg: AdvisorSettings,
               every: float = 3600.0) -> list[Situation]:
    """One situation per ``every`` seconds of the recording (module docstring).
    ``estimates`` and ``health`` are ``(log_time_ns, body)`` in log-time order."""
    chosen: list[Mapping[str, Any]] = []
    last_slot = None
    for _, body in estimates:
        end = body.get("window_end_ns")
        if end is None:
            continue
        slot = int(end) // int(every * 1e9)
        if slot != last_slot:
            chosen.append(body)
            last_slot = slot
    if not chosen:
        return []
    start = np.array([int(b["window_start_ns"]) for b in chosen], np.int64)
    end = np.array([int(b["window_end_ns"]) for b in chosen], np.int64)
    means = _window_means(scans, start, end)
    width = np.maximum(end - start, 1)
    n_back = np.maximum(np.round(cfg.steady_window * 1e9 / width).astype(int), 1)
    h_times = [t for t, _ in health]
    col = {n: i for i, n in enumerate(SCAN_SIGNALS)}
    out = []
    for k, body in enumerate(chosen):
        back_start = end[k] - (np.arange(n_back[k], 0, -1)) * width[k]
        back = _window_means(scans, back_start, back_start + width[k])
        j = bisect.bisect_right(h_times, int(end[k])) - 1
        hb = health[j][1] if j >= 0 else {"status": body.get("status", "ok"),
                                          "detail": body.get("detail", "")}
        out.append(Situation(
            time_ns=int(end[k]),
            inputs={n: float(means[k, i]) for n, i in col.items()},
            moisture_in=_num(body.get("moisture_in")),
            moisture_out=_num(body.get("moisture_out")),
            moisture_out_std=_num(body.get("moisture_out_std")),
            health=str(hb.get("status", "degraded")), health_detail=str(hb.get("detail", "")),
            recent_m_fiber=tuple(back[:, col["m_fiber"]]),
            recent_T_sp=tuple(back[:, col["T_sp"]])))
    return out


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def refusal_kind(reason: str) -> str:
    """The kind of a refusal, for counting: its reason up to the first colon or number."""
    head = re.split(r"[:(]|\d", reason, maxsplit=1)[0].strip()
    return head or reason


@dataclass(frozen=True)
class WhatIf:
    """What following the advice hour by hour would have changed (module docstring).

    Attributes
    ----------
    hours, hours_advised : int
    energy_saved_kwh : float
        Heat saved over the advised hours against the set point as run. [kWh]
    fibre_t : float
        Dry fibre produced over the advised hours. [t]
    saved_kwh_per_t : float
        ``energy_saved_kwh / fibre_t`` [kWh/t] (NaN without advised hours).
    duty_kwh_per_t : float
        Heat per tonne as run over the advised hours. [kWh/t]
    expected_hours_above_max : float
        Sum over the advised hours of the probability of exceeding ``moisture_max``. [h]
    hours_above_max_as_run : int
        Hours whose estimate was above ``moisture_max`` as run (all hours with an estimate).
    refusals : dict
        Refused hours per kind of reason.
    """

    hours: int
    hours_advised: int
    energy_saved_kwh: float
    fibre_t: float
    saved_kwh_per_t: float
    duty_kwh_per_t: float
    expected_hours_above_max: float
    hours_above_max_as_run: int
    refusals: dict[str, int]

    def to_body(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in self.__dict__.items()}


def what_if(advices: Sequence[Advice], sits: Sequence[Situation], cfg: AdvisorSettings,
            every: float = 3600.0) -> WhatIf:
    """The sums of :class:`WhatIf` over one advice per ``every`` seconds."""
    hours = every / 3600.0
    saved = fibre = duty = 0.0
    p_above = 0.0
    n_adv = 0
    above_run = 0
    refusals: Counter[str] = Counter()
    for a, s in zip(advices, sits, strict=True):
        if s.moisture_out is not None and s.moisture_out > cfg.moisture_max:
            above_run += 1
        if not a.advised:
            refusals[refusal_kind(a.reason)] += 1
            continue
        n_adv += 1
        t = float(s.inputs["m_fiber"]) * 3.6 * hours
        fibre += t
        saved += (a.duty_kw - a.duty_advised_kw) * hours
        duty += a.duty_kw * hours
        p_above += 1.0 - float(a.p_within_max)
    return WhatIf(len(advices), n_adv, saved, fibre, saved / fibre if fibre else math.nan,
                  duty / fibre if fibre else math.nan, p_above * hours, above_run,
                  dict(refusals.most_common()))


__all__ = ["WhatIf", "refusal_kind", "situations", "what_if"]
