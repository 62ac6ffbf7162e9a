"""What the daemon and the replay build alike: the estimator service of a plant config.

``softsensor run`` (:mod:`.daemon`) and ``softsensor replay`` (:mod:`.offline_replay`) run the
same :class:`~softsensor.service.estimator_service.EstimatorService`, built here from the
config's tables (built once, :mod:`softsensor.plantconfig`): its windowing is the core's
(:func:`~softsensor.windows.accumulator.window_settings`, ``[solver]`` and
``[plausibility]``) at the scan period the caller knows, its estimator the config's
``estimator.kind`` unless the command line names another, its bounds the ``[service]`` table's.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from softsensor.estimation.settings import estimator_settings
from softsensor.ingest.tagmap import load_tagmap
from softsensor.plantconfig import PlantConfig
from softsensor.service.estimator_service import EstimatorService
from softsensor.service.estimators import make_estimator
from softsensor.service.settings import ServiceSettings, resolve_unit
from softsensor.windows.accumulator import WindowSettings, window_settings
from softsensor.windows.plausibility import Plausibility, estimate_ranges


def service_window(cfg: PlantConfig, settings: ServiceSettings,
                   scan_period_s: float | None = None) -> WindowSettings:
    """The service's windowing: the core's, at ``solver.scan_period`` when set, else
    ``scan_period_s`` (live: the poll period; replay: measured from the day), else the tag
    map's poll period [s]."""
    if scan_period_s is None and cfg.solver.scan_period is None:
        tagmap = load_tagmap(settings.tagmap) if settings.tagmap else load_tagmap()
        scan_period_s = tagmap.modbus.poll_period_s
    return window_settings(cfg, scan_period_s)


def make_service(cfg: PlantConfig, settings: ServiceSettings, kind: str | None = None,
                 scan_period_s: float | None = None, *,
                 time_gate: Callable[[int], str | None] | None = None) -> EstimatorService:
    """The estimator service of ``cfg`` (``kind``: the estimator, None for the config's
    ``estimator.kind``; the scan period in plant s, see :func:`service_window`; ``time_gate``:
    the daemon's refusal of times far from its clock, None in a replay)."""
    window = service_window(cfg, settings, scan_period_s)
    # a gap is ticked window by window up to the past horizon the service accepts data for;
    # longer ones are one "stale since" state (a scan stamped years ahead costs no more)
    max_gap = max(1, math.ceil(settings.max_past_s / window.period_s))
    est = estimator_settings(cfg)
    ranges = estimate_ranges(window.plausibility or Plausibility(),
                             (est.moisture_in_min, est.moisture_in_max))
    return EstimatorService(make_estimator(kind, cfg), window,
                            unit=resolve_unit(settings, cfg),
                            tick_delay_s=settings.tick_delay_s, gap_after_s=settings.gap_after_s,
                            max_gap_windows=max_gap, ranges=ranges,
                            max_lab_silence_s=(settings.max_lab_silence_h * 3600.0
                                               if settings.max_lab_silence_h > 0 else None),
                            time_gate=time_gate)


__all__ = ["make_service", "service_window"]
