"""Prometheus metrics of the daemon (``[outputs.prometheus]``), by ``prometheus_client``.

The estimate and its band are gauges set on every tick; the counters of the estimator, the
poller and the lab input are read from their ``stats`` when Prometheus scrapes (callbacks), so
the numbers are the ones the daemon's status line prints. A registry of its own (not the
process-global one) keeps tests and several daemons in one process apart. Served by
``prometheus_client``'s own HTTP server on loopback unless configured.

Metric names follow Prometheus' conventions: base units in the name, ``_total`` for
counters, ``_seconds`` for durations; moisture stays kg/kg on a dry basis (SI, like every
interface the program offers to other programs).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from prometheus_client import CollectorRegistry, Gauge, Histogram, start_http_server
from prometheus_client.core import CounterMetricFamily

from softsensor.errors import ConfigError
from softsensor.outputs.settings import MetricsSettings

HEALTH_STATES: tuple[str, ...] = ("ok", "degraded", "stale")
_ESTIMATES = ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std")


class _Counters:
    """Counters read from the daemon's parts at scrape time (a custom collector, so they are
    exposed as counters, not gauges)."""

    def __init__(self, counters: Mapping[str, tuple[str, Callable[[], float]]]) -> None:
        self.counters = dict(counters)

    def collect(self):
        for name, (doc, fn) in self.counters.items():
            try:
                value = float(fn())
            except Exception:  # noqa: BLE001 - a part not started yet: no sample this scrape
                continue
            yield CounterMetricFamily(name, doc, value=value)


class DaemonMetrics:
    """The daemon's metrics (module docstring). ``counters`` maps a counter's name (without
    ``_total``) to its help text and a function returning its current value, read at scrape
    time."""

    def __init__(self, settings: MetricsSettings,
                 counters: Mapping[str, tuple[str, Callable[[], float]]] | None = None) -> None:
        self.settings = settings
        self.registry = CollectorRegistry()
        r = self.registry
        self.estimate = {k: Gauge(f"softsensor_{k}_kg_per_kg",
                                  f"latest {k} estimate [kg/kg dry basis]", registry=r)
                         for k in _ESTIMATES}
        for g in self.estimate.values():
            g.set(math.nan)
        self.window_end = Gauge("softsensor_window_end_seconds",
                                "end of the latest estimated window [s since the epoch]",
                                registry=r)
        self.health = Gauge("softsensor_health", "1 for the current health status",
                            ["status"], registry=r)
        self.tick = Histogram("softsensor_tick_duration_seconds",
                              "wall time the estimator took for one tick [s]",
                              buckets=(0.01, 0.05, 0.1, 0.5, 1, 5, 30, 60, 300, 600, 1200),
                              registry=r)
        r.register(_Counters(counters or {}))
        self._server: Any = None
        self.port = settings.port

    def start(self) -> None:
        """Serve ``/metrics``; a port in use is a one-line error naming the table."""
        s = self.settings
        try:
            self._server, _thread = start_http_server(s.port, s.host, registry=self.registry)
        except OSError as exc:
            raise ConfigError(f"outputs.prometheus: cannot listen on {s.host}:{s.port}: "
                              f"{exc.strerror or exc}") from exc
        self.port = self._server.server_address[1]

    def publish(self, body: Mapping[str, Any], time_ns: int, duration_s: float | None = None
                ) -> None:
        """Set the gauges from an estimate body; ``duration_s``: the tick's wall time."""
        for k, g in self.estimate.items():
            v = body.get(k)
            g.set(math.nan if v is None else float(v))
        self.window_end.set(time_ns / 1e9)
        self.set_health(str(body.get("status")))
        if duration_s is not None:
            self.tick.observe(duration_s)

    def set_health(self, status: str) -> None:
        for s in HEALTH_STATES:
            self.health.labels(status=s).set(1.0 if s == status else 0.0)

    def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.shutdown()
            server.server_close()


__all__ = ["HEALTH_STATES", "DaemonMetrics"]
