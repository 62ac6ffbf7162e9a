"""The set-point advisor in the daemon: every tick's advice, published on
``softsensor/<unit>/advice`` and handed to the operator outputs.

With ``[advisor] enabled = true`` the daemon builds an :class:`AdvisorTap`
(:func:`advisor_tap`): it keeps the scans the worker admitted over the last
``steady_window`` plus a window, and after each estimate the daemon publishes builds the
tick's :class:`~softsensor.advisor.advice.Situation` (the window's scan means, the estimate,
the health in force, the recent production and set point) and asks
:func:`~softsensor.advisor.advice.advise`. The advice (or the one line why there is none) goes
out on the bus and to every operator output that serves it (``on_advice``). Advisory only:
nothing is written to the PLC. The parameters' covariance is read once, at start, from
``[advisor] identify`` (the JSON of ``softsensor identify --json``).
"""

from __future__ import annotations

import collections
import json
import logging
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.advisor.advice import Advice, Envelope, advise
from softsensor.advisor.settings import AdvisorSettings, advisor_settings
from softsensor.errors import ConfigError
from softsensor.estimate import SEVERITY, Estimate, Health
from softsensor.estimation.model_error import model_error_of
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import SCAN_SIGNALS

log = logging.getLogger(__name__)


def covariance_from_identify(path: str | Path, flag: str = "--identify") -> np.ndarray:
    """The parameters' covariance in ln(theta) (7, 7) from ``softsensor identify --json``:
    ``diag(se) R diag(se)``. Raises :class:`~softsensor.errors.ConfigError` naming the file."""
    try:
        doc = json.loads(Path(path).read_text())
        se = np.array([float(doc["verdicts"][n]["relative_se"]) for n in PARAMETER_NAMES])
        R = np.asarray(doc["correlation"], float)
    except FileNotFoundError as exc:
        raise ConfigError(f"{flag} {path}: no such file") from exc
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{flag} {path}: not the JSON of softsensor identify "
                          f"({type(exc).__name__}: {exc})") from exc
    if R.shape != (len(PARAMETER_NAMES),) * 2 or not np.all(np.isfinite(se)):
        raise ConfigError(f"{flag} {path}: correlation must be 7 x 7 and every relative_se "
                          "finite")
    return np.outer(se, se) * R


class AdvisorTap:
    """Scans in, one advice per estimate out (module docstring)."""

    def __init__(self, config: PlantConfig, settings: AdvisorSettings, cov: np.ndarray,
                 env: Envelope, model: DryerModel | None = None) -> None:
        self.settings = settings
        # on the estimator's thread, one core (``model``: another grid, e.g. in tests)
        self.model = DryerModel(config, threads=1) if model is None else model
        self.theta = config.parameter_vector()
        self.cov = cov
        self.env = env
        self.keep_ns = int((settings.steady_window + 2 * config.solver.window) * 1e9)
        self._scans: collections.deque[tuple[int, dict[str, Any]]] = collections.deque()
        self._lock = threading.Lock()
        self.latest: Advice | None = None

    def on_scan(self, time_ns: int | None, body: dict[str, Any]) -> None:
        """Keep an admitted scan (any thread)."""
        if time_ns is None:
            return
        with self._lock:
            self._scans.append((int(time_ns), {n: body.get(n) for n in SCAN_SIGNALS}))
            while self._scans and self._scans[0][0] < time_ns - self.keep_ns:
                self._scans.popleft()

    def on_estimate(self, est: Estimate, health: Health | None) -> Advice:
        """The advice at ``est`` with the health in force (the estimate's own when None)."""
        # here: pandas (about 60 MB resident) only in a daemon that advises (issue 49)
        import pandas as pd

        from softsensor.advisor.replay import situations

        with self._lock:
            rows = list(self._scans)
        scans = pd.DataFrame([r for _, r in rows], index=[t for t, _ in rows],
                             columns=list(SCAN_SIGNALS), dtype=float)
        body = est.to_body()
        # the worse of the estimate's own status and the health in force
        src = est if health is None or SEVERITY.get(est.status, 1) >= SEVERITY.get(
            health.status, 1) else health
        hb = [(est.time_ns, {"status": src.status, "detail": src.detail})]
        sits = situations(scans.sort_index(), [(est.time_ns, body)], hb, self.settings)
        self.latest = advise(self.model, self.theta, self.cov, sits[0], self.settings,
                             self.env)
        return self.latest

    def after(self, out: Any, health: Health | None, put, outputs: Iterable[Any]) -> None:
        """After the daemon published ``out``: for an estimate, advise, publish the advice with
        ``put(kind, body, time_ns)`` and hand it to each output that serves it. A failure is
        logged, never raised (the estimate is out already)."""
        if not isinstance(out, Estimate):
            return
        try:
            a = self.on_estimate(out, health)
            put("advice", a.to_body(), a.time_ns)
            for o in outputs:
                serve = getattr(o, "on_advice", None)
                if serve is not None:
                    serve(a)
        except Exception:  # noqa: BLE001 - the advisor must never stop the estimator
            log.exception("advice failed")


def admitted_chain(tap: AdvisorTap | None, recorder: Any | None):
    """The worker's ``on_admitted`` hook: the bus recorder's ``record`` and the tap's scans
    (None when neither runs)."""
    if tap is None:
        return None if recorder is None else recorder.record

    def admitted(message: Any, origin: str) -> None:
        if recorder is not None:
            recorder.record(message, origin)
        if message.kind == "scan":
            tap.on_scan(message.time_ns, message.body)

    return admitted


def advisor_tap(config: PlantConfig) -> AdvisorTap | None:
    """The daemon's tap when ``[advisor] enabled`` (None otherwise). Raises
    :class:`~softsensor.errors.ConfigError` for a missing covariance or ``[model_error]``."""
    s = advisor_settings(config)
    if not s.enabled:
        return None
    me = model_error_of(config)
    if me is None:
        raise ConfigError("[advisor] enabled needs parameters with a [model_error] table (the "
                          "history's envelope): calibrate from history")
    cov = covariance_from_identify(s.identify, "advisor.identify")
    return AdvisorTap(config, s, cov, Envelope.of(me, s.envelope_sd))


__all__ = ["AdvisorTap", "admitted_chain", "advisor_tap", "covariance_from_identify"]
