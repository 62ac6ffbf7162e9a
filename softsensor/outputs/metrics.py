"""Prometheus metrics of the daemon (``[outputs.prometheus]``), by ``prometheus_client``.

The estimate and its band are gauges set on every tick; the counters of the estimator, the
poller and the lab input are read from their ``stats`` when Prometheus scrapes (callbacks), so
the numbers are the ones the daemon's status line prints. A registry of its own (not the
process-global one) keeps tests and several daemons in one process apart. Served by
``prometheus_client``'s own HTTP server on loopback unless configured.

Every sample carries the labels ``dryer`` (the unit name, ``dryer1``) and ``site`` (the
table's ``site``), so one Prometheus scrapes several dryers and sites and a dashboard chooses
among them (``docs/grafana/softsensor.json``); and, with the same value as ``dryer``, the
label ``unit`` it was called before (deprecated: in metrics "unit" means a unit of measure,
so queries written with it keep working while they move to ``dryer``). Metric names follow
Prometheus' conventions: base units in the name, ``_total`` for counters, ``_seconds`` for
durations, ``_timestamp_seconds`` for times, ``_ratio`` for a dimensionless ratio (kg of water
per kg of dry fibre), ``_celsius`` for temperatures. The two renamed (``_kg_per_kg`` to
``_ratio``, ``softsensor_window_end_seconds`` to ``softsensor_window_end_timestamp_seconds``)
are also served under their old names, marked deprecated in their help, for the dashboards and
alerts that use them. Moisture is given twice: as a dry-basis ratio (SI, like every interface
the program offers to other programs) and in % on a wet basis (what a plant's lab and
operators read), with the 95 % band (its low end clipped at bone dry,
:func:`~softsensor.presentation.display.moisture_band`) and the ``[display]`` target and acceptable
band, so a dashboard plots them without arithmetic.

``/metrics`` is served by the web page's server
(:class:`~softsensor.outputs.deadline_http.DeadlineHTTPServer`): a header deadline of
``timeout_s``, at most ``workers + backlog`` connections, ``workers`` threads.
``prometheus_client``'s own server spawned a thread per client and had no header deadline
(issue 40: 500 slow clients held 522 threads and 535 descriptors).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any
from urllib.parse import urlsplit

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Gauge,
    Histogram,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.deadline_http import DeadlineHTTPServer, Response
from softsensor.outputs.settings import MetricsSettings
from softsensor.presentation.display import DisplaySettings, moisture_band, moisture_pct

HEALTH_STATES: tuple[str, ...] = ("ok", "degraded", "stale")
_ESTIMATES = ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std")
#: The labels of every metric (``unit``: deprecated, the same value as ``dryer``).
LABELS: tuple[str, ...] = ("dryer", "site", "unit")
#: Outlet temperatures: (channel, source) -> key of the estimate body.
_TEMPERATURES = {(c, s): f"{c}_{s}" for c in ("T_dryer_out", "T_cyclone_out")
                 for s in ("measured", "model")}


class _Counters:
    """Counters read from the daemon's parts at scrape time (a custom collector, so they are
    exposed as counters, not gauges)."""

    def __init__(self, counters: Mapping[str, tuple[str, Callable[[], float]]],
                 labels: tuple[str, ...]) -> None:
        self.counters, self.labels = dict(counters), labels

    def collect(self):
        for name, (doc, fn) in self.counters.items():
            try:
                value = float(fn())
            except Exception:  # noqa: BLE001 - a part not started yet: no sample this scrape
                continue
            family = CounterMetricFamily(name, doc, labels=LABELS)
            family.add_metric(list(self.labels), value)
            yield family


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


class DaemonMetrics:
    """The daemon's metrics (module docstring), an
    :class:`~softsensor.outputs.operator_output.OperatorOutput`. ``counters`` maps a
    counter's name (without ``_total``) to its help text and a function returning its current
    value, read at scrape time; ``tick_seconds`` returns the wall time the last tick took
    [s] (None: not known), observed with every estimate."""

    name = "prometheus"

    def __init__(self, settings: MetricsSettings,
                 counters: Mapping[str, tuple[str, Callable[[], float]]] | None = None, *,
                 unit: str = "dryer1", display: DisplaySettings | None = None,
                 tick_seconds: Callable[[], float | None] | None = None) -> None:
        self.settings = settings
        self._tick_seconds = tick_seconds
        self.display = display or DisplaySettings()
        self.registry = CollectorRegistry()
        self.labels = {"dryer": unit, "site": settings.site, "unit": unit}
        r, lab = self.registry, list(LABELS)

        def gauge(name: str, doc: str, extra: tuple[str, ...] = ()) -> Gauge:
            return Gauge(name, doc, [*lab, *extra], registry=r)

        self.estimate = {k: gauge(f"softsensor_{k}_ratio",
                                  f"latest {k} estimate [kg water / kg dry fibre]")
                         for k in _ESTIMATES}
        self.deprecated = {k: gauge(f"softsensor_{k}_kg_per_kg",
                                    f"deprecated: use softsensor_{k}_ratio (the same value)")
                           for k in _ESTIMATES}
        self.wet = {k: gauge(f"softsensor_{k}_wet_basis_percent",
                             f"latest {k} estimate [% wet basis]")
                    for k in ("moisture_out", "moisture_in")}
        self.band = gauge("softsensor_moisture_out_band_wet_basis_percent",
                          "95 % band of the outlet moisture [% wet basis]", ("bound",))
        self.limits = gauge("softsensor_moisture_out_limit_wet_basis_percent",
                            "outlet moisture target and acceptable band of [display] "
                            "[% wet basis]", ("level",))
        self.temperature = gauge("softsensor_outlet_temperature_celsius",
                                 "outlet temperature, window mean of the measurement or the "
                                 "model's [°C]", ("channel", "source"))
        self.window_end = gauge("softsensor_window_end_timestamp_seconds",
                                "end of the latest estimated window [s since the epoch]")
        self.window_end_old = gauge("softsensor_window_end_seconds",
                                    "deprecated: use softsensor_window_end_timestamp_seconds")
        self.health = gauge("softsensor_health", "1 for the current health status",
                            ("status",))
        # the set-point advisor's (softsensor.service.advisor_tap), NaN until it advises
        self.advice = {k: gauge(f"softsensor_advice_{k}", doc, extra) for k, doc, extra in (
            ("given", "1 when the advisor gives advice, 0 when it refuses", ()),
            ("setpoint_celsius", "outlet-temperature set point now and advised [°C]",
             ("which",)),
            ("heat_kwh_per_tonne", "burner heat per tonne of dry fibre now and at the advised "
             "set point [kWh/t]", ("which",)),
            ("settle_seconds", "time to settle at the advised set point [s]", ()))}
        self.tick = Histogram("softsensor_tick_duration_seconds",
                              "wall time the estimator took for one tick [s]", lab,
                              buckets=(0.01, 0.05, 0.1, 0.5, 1, 5, 30, 60, 300, 600, 1200),
                              registry=r)
        for g in (*self.estimate.values(), *self.deprecated.values(), *self.wet.values()):
            g.labels(**self.labels).set(math.nan)
        for bound in ("low", "high"):
            self.band.labels(**self.labels, bound=bound).set(math.nan)
        d = self.display
        for level, x in (("target", d.moisture_target), ("low", d.moisture_low),
                         ("high", d.moisture_high)):
            self.limits.labels(**self.labels, level=level).set(float(moisture_pct(x)))
        for channel, source in _TEMPERATURES:
            self.temperature.labels(**self.labels, channel=channel, source=source).set(math.nan)
        self._set_health("stale")
        r.register(_Counters(counters or {}, (unit, settings.site, unit)))
        self._server: DeadlineHTTPServer | None = None
        self.port = settings.port

    def answer(self, target: str) -> Response:
        """``/metrics`` in Prometheus' text format; anything else 404."""
        if urlsplit(target).path != "/metrics":
            return Response(404, "text/plain", "not found: see /metrics\n")
        return Response(200, CONTENT_TYPE_LATEST, generate_latest(self.registry))

    async def start(self) -> str:
        """Serve ``/metrics``; a port in use is a one-line error naming the table. What it
        serves: the URL."""
        s = self.settings
        server = DeadlineHTTPServer(s.host, s.port, self.answer, workers=s.workers,
                                    max_connections=s.workers + s.backlog,
                                    header_timeout_s=s.timeout_s)
        try:
            server.start()
        except OSError as exc:
            raise ConfigError(f"outputs.prometheus: cannot listen on {s.host}:{s.port}: "
                              f"{exc.strerror or exc}") from exc
        self._server = server
        self.port = server.port
        return f"http://{s.host}:{self.port}/metrics"

    @property
    def expired(self) -> int:
        """Connections closed because their header missed the deadline."""
        return 0 if self._server is None else self._server.expired

    def on_estimate(self, estimate: Estimate) -> None:
        """Set the gauges from an estimate, and observe the tick's wall time."""
        body, time_ns = estimate.to_body(), estimate.time_ns
        lab = self.labels
        for k, g in self.estimate.items():
            g.labels(**lab).set(_num(body.get(k)))
            self.deprecated[k].labels(**lab).set(_num(body.get(k)))
        for k, g in self.wet.items():
            g.labels(**lab).set(float(moisture_pct(_num(body.get(k)))))
        low, high = moisture_band(_num(body.get("moisture_out")),
                                  _num(body.get("moisture_out_std")))
        self.band.labels(**lab, bound="low").set(float(moisture_pct(low)))
        self.band.labels(**lab, bound="high").set(float(moisture_pct(high)))
        for (channel, source), key in _TEMPERATURES.items():
            self.temperature.labels(**lab, channel=channel, source=source).set(
                _num(body.get(key)) - 273.15)
        self.window_end.labels(**lab).set(time_ns / 1e9)
        self.window_end_old.labels(**lab).set(time_ns / 1e9)
        self._set_health(estimate.status)
        duration_s = None if self._tick_seconds is None else self._tick_seconds()
        if duration_s is not None:
            self.tick.labels(**lab).observe(duration_s)

    def on_health(self, health: Health) -> None:
        self._set_health(health.status)

    def on_advice(self, advice: Any) -> None:
        """Set the advisor's gauges (an :class:`~softsensor.advisor.advice.Advice`; its
        numbers NaN when it refuses)."""
        lab, g = self.labels, self.advice
        g["given"].labels(**lab).set(1.0 if advice.advised else 0.0)
        for which, sp, q in (("now", advice.T_sp, advice.duty_kwh_per_t),
                             ("advised", advice.T_sp_advised, advice.duty_advised_kwh_per_t)):
            g["setpoint_celsius"].labels(**lab, which=which).set(_num(sp) - 273.15)
            g["heat_kwh_per_tonne"].labels(**lab, which=which).set(_num(q))
        g["settle_seconds"].labels(**lab).set(_num(advice.settle_s))

    def on_lab(self, lab: LabResult) -> None:
        """Lab results are counted by the service (its counters), not here."""

    def _set_health(self, status: str) -> None:
        for s in HEALTH_STATES:
            self.health.labels(**self.labels, status=s).set(1.0 if s == status else 0.0)

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            server.stop()


__all__ = ["HEALTH_STATES", "LABELS", "DaemonMetrics"]
