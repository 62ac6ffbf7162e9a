"""Compile the estimator before the stream starts: a throwaway service ticks synthetic windows.

numba compiles each kernel (or loads it from its on-disk cache) at its first call. Building the
estimator compiles the model's steady state, but the first tick calls more (the sigma-point
batch, the lab update and the refilter a late lab starts). With a cold cache that first tick
took 23 s on an idle two-core machine, tens of seconds more on a loaded one, and the estimator
thread holds every message meanwhile: the replay, which calls 60 s without progress a stall
(:data:`~softsensor.service.offline_replay.STALL_TIMEOUT_S`), could fail on it, and the daemon
would start a live day minutes behind.

:func:`warm_up` runs a *separate* service, built by the same factory as the real one, through
three windows of scans at the config's nominal operating point with one late lab result, so
every path of a tick runs once. The real service never sees these messages: its estimates stay
a function of the day alone (a replay with and without warm-up gives the same estimates).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from softsensor.plantconfig import PlantConfig
from softsensor.service.estimator_service import EstimatorService, ServiceStats

log = logging.getLogger(__name__)

NS = 10**9
#: About where the synthetic windows start (2026-01-01T00:00:00Z); moved back onto a window
#: boundary, since windows end on multiples of their length since the epoch.
_START_NS = 1_767_225_600 * NS
#: Windows ticked: one to get a model estimate, one holding the lab's sample time, one in
#: which the lab arrives late (the refilter path).
N_WINDOWS = 3


def _scan(cfg: PlantConfig, last: dict[str, Any] | None) -> dict[str, float]:
    """A scan at the nominal point; outlet temperatures from the last estimate when there is one
    (so the filter sees consistent data and takes its ordinary path)."""
    n = cfg.nominal
    body = {"T_air_in": n.T_air_in, "m_air": n.m_air, "m_fiber": n.m_fiber,
            "T_fiber_in": n.T_fiber_in, "m_steam": n.m_steam, "T_amb": n.T_amb,
            "H_amb": n.H_amb, "flap_cmd": 50.0, "T_sp": n.T_sp,
            "T_dryer_out": n.T_sp, "T_cyclone_out": n.T_sp - 4.0}
    for channel in ("T_dryer_out", "T_cyclone_out"):
        v = (last or {}).get(f"{channel}_model")
        if isinstance(v, float) and math.isfinite(v):
            body[channel] = v
    return body


@dataclass(frozen=True)
class WarmUp:
    """What :func:`warm_up` did: wall seconds, the throwaway service's counters (None when it
    could not be built) and the error that ended it early (None when it ran through)."""

    seconds: float
    stats: ServiceStats | None = None
    error: str | None = None


def warm_up(make: Callable[[], EstimatorService], cfg: PlantConfig) -> WarmUp:
    """Tick a throwaway service from ``make()`` through :data:`N_WINDOWS` synthetic windows.

    Never raises for the estimator's sake: a warm-up that fails is logged and the real service
    starts anyway (it would meet the same failure on its data, where the service reports it as
    health).
    """
    t0 = time.monotonic()
    service: EstimatorService | None = None
    try:
        service = make()
        service.synthetic = True  # its lab line must not read as a plant's result
        period_ns = int(round(service.window.period_s * NS))
        scan_ns = int(round(service.window.scan_period_s * NS))
        start = _START_NS // period_ns * period_ns
        last: dict[str, Any] | None = None
        lab_sent = False
        t = start + scan_ns
        end = start + N_WINDOWS * period_ns
        while t <= end:
            for out in service.on_scan(t, _scan(cfg, last)):
                if out.kind == "estimate":
                    last = out.to_body()
            k = (t - start) // period_ns  # windows completed before t
            mo = (last or {}).get("moisture_out")
            if k >= 2 and not lab_sent and isinstance(mo, float) and math.isfinite(mo):
                # sampled in the middle of window 2, reported in window 3: a late lab that
                # agrees with the model (an outlier screen would refuse a made-up value)
                sample_ns = start + period_ns + period_ns // 2
                service.on_lab({"sample_time_ns": sample_ns, "moisture_out": mo,
                                "sample_id": "warm-up"}, t)
                lab_sent = True
            t += scan_ns
        service.flush()
    except Exception as exc:  # noqa: BLE001 - warming up is an optimisation, never fatal
        seconds = time.monotonic() - t0
        error = f"{type(exc).__name__}: {exc}"
        log.warning("estimator warm-up failed after %.1f s (%s); the first tick will compile "
                    "instead", seconds, error)
        return WarmUp(seconds, None if service is None else service.stats, error)
    s = service.stats
    seconds = time.monotonic() - t0
    log.debug("warm-up: %d ticks, %d lab updates, %d failed, %.1f s", s.ticks, s.lab_updates,
              s.failed_ticks, seconds)
    return WarmUp(seconds, s)


__all__ = ["N_WINDOWS", "WarmUp", "warm_up"]
