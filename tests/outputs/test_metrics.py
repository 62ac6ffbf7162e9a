"""The Prometheus metrics (``softsensor/outputs/metrics.py``), read by ``prometheus_client``'s own
parser on 127.0.0.1: the estimate in plant units, the counters read live, the names a
dashboard keeps, the band clipped at bone dry, and a busy port refused in one line."""

from __future__ import annotations

import asyncio
import math
import urllib.request

import pytest
from clients import scrape_metrics
from sample_estimate import BODY, T_NS

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate
from softsensor.outputs.metrics import DaemonMetrics
from softsensor.outputs.settings import MetricsSettings
from softsensor.presentation.display import DisplaySettings


def test_prometheus_names_a_ratio_and_a_timestamp_keeps_the_old_and_clips_the_band():
    """kg/kg is a ``_ratio``, the window end a ``_timestamp_seconds``, the dryer a ``dryer``
    label; the old names and the ``unit`` label are still served (deprecated) so existing
    dashboards keep working; a start-up band wider than the estimate stops at 0 % (it ran
    the axis to -10 % wb)."""
    from prometheus_client.parser import text_string_to_metric_families

    from softsensor.outputs.metrics import DaemonMetrics
    from softsensor.outputs.settings import MetricsSettings

    m = DaemonMetrics(MetricsSettings(enabled=True, port=0, site="mill"),
                      {"softsensor_ticks": ("ticks", lambda: 3)}, unit="dryer2")
    asyncio.run(m.start())
    try:
        m.on_estimate(Estimate.from_body({
            "moisture_out": 0.03, "moisture_out_std": 0.03, "moisture_in": 1.0,
            "moisture_in_std": 0.02, "status": "ok", "window_end_ns": 1_767_607_800 * 10**9}))
        text = urllib.request.urlopen(f"http://127.0.0.1:{m.port}/metrics",
                                      timeout=5).read().decode()
    finally:
        asyncio.run(m.stop())
    samples = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            labels = dict(s.labels)
            assert labels.pop("dryer") == labels.pop("unit") == "dryer2", s
            assert labels.pop("site") == "mill", s
            samples[s.name + str(sorted(labels.items()))] = (s.value, fam.documentation)
    assert samples["softsensor_moisture_out_ratio[]"][0] == pytest.approx(0.03)
    value, doc = samples["softsensor_moisture_out_kg_per_kg[]"]
    assert value == pytest.approx(0.03) and doc.startswith("deprecated: use")
    assert samples["softsensor_window_end_timestamp_seconds[]"][0] == 1_767_607_800
    assert samples["softsensor_window_end_seconds[]"][0] == 1_767_607_800
    assert samples["softsensor_ticks_total[]"][0] == 3
    assert samples["softsensor_moisture_out_band_wet_basis_percent[('bound', 'low')]"][0] == 0.0


def test_metrics_parse_with_prometheus_client_and_read_the_counters_live():
    ticks = [3]
    m = DaemonMetrics(MetricsSettings(enabled=True, port=0, site="mill-north"),
                      {"softsensor_ticks": ("ticks", lambda: ticks[0])}, unit="dryer2",
                      display=DisplaySettings(moisture_basis="dry"), tick_seconds=lambda: 0.04)
    asyncio.run(m.start())
    try:
        first = scrape_metrics(m.port, "dryer2", "mill-north")
        assert math.isnan(first["softsensor_moisture_out_kg_per_kg"])
        body = {**BODY, "T_dryer_out_measured": 348.65, "T_dryer_out_model": 348.15}
        m.on_estimate(Estimate.from_body({**body, "window_end_ns": T_NS}))
        ticks[0] = 4
        got = scrape_metrics(m.port, "dryer2", "mill-north")
        # % wet basis whatever the display basis (what a lab and an operator read)
        wet = 100 * 0.1034 / 1.1034
        assert got["softsensor_moisture_out_wet_basis_percent"] == pytest.approx(wet)
        assert got["softsensor_moisture_in_wet_basis_percent"] == pytest.approx(
            100 * 1.0312 / 2.0312)
        low = got["softsensor_moisture_out_band_wet_basis_percent[('bound', 'low')]"]
        high = got["softsensor_moisture_out_band_wet_basis_percent[('bound', 'high')]"]
        assert low < wet < high and high - low == pytest.approx(
            100 * (0.1034 + 1.96 * 0.0042) / (1.1034 + 1.96 * 0.0042)
            - 100 * (0.1034 - 1.96 * 0.0042) / (1.1034 - 1.96 * 0.0042))
        assert got["softsensor_moisture_out_limit_wet_basis_percent[('level', 'target')]"] \
            == pytest.approx(100 * 0.10 / 1.10)
        assert got["softsensor_outlet_temperature_celsius[('channel', 'T_dryer_out'), "
                   "('source', 'measured')]"] == pytest.approx(75.5)
        assert got["softsensor_outlet_temperature_celsius[('channel', 'T_dryer_out'), "
                   "('source', 'model')]"] == pytest.approx(75.0)
        assert got["softsensor_moisture_out_kg_per_kg"] == pytest.approx(0.1034)
        assert got["softsensor_moisture_in_std_kg_per_kg"] == pytest.approx(0.021)
        assert got["softsensor_window_end_seconds"] == pytest.approx(T_NS / 1e9)
        assert got["softsensor_health[('status', 'degraded')]"] == 1.0
        assert got["softsensor_health[('status', 'ok')]"] == 0.0
        assert got["softsensor_ticks_total"] == 4.0
        assert got["softsensor_tick_duration_seconds_count"] == 1.0
        assert got["softsensor_tick_duration_seconds_sum"] == pytest.approx(0.04)
    finally:
        asyncio.run(m.stop())


def test_a_port_in_use_is_a_one_line_error():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        m = DaemonMetrics(MetricsSettings(enabled=True, port=port))
        with pytest.raises(ConfigError, match=rf"outputs\.prometheus: cannot listen on "
                                              rf"127\.0\.0\.1:{port}"):
            asyncio.run(m.start())


def test_slow_clients_hold_no_thread_and_are_closed_at_the_header_deadline():
    """Issue 40: ``prometheus_client``'s server spawned a thread per client with no header
    deadline (500 slow clients, 522 threads, 535 descriptors); now the web page's server:
    ``workers`` threads, ``workers + backlog`` connections, scrapes answered throughout."""
    import socket
    import threading
    import time

    m = DaemonMetrics(MetricsSettings(enabled=True, port=0, workers=2, backlog=6,
                                      timeout_s=0.5))
    threads_before = threading.active_count()
    asyncio.run(m.start())
    slow = []
    try:
        for _ in range(300):  # each sends half a header and then nothing
            s = socket.create_connection(("127.0.0.1", m.port), timeout=5)
            s.sendall(b"GET /metrics HTTP/1.1\r\nHost: x\r\n")
            slow.append(s)
        assert threading.active_count() - threads_before <= 2 + 1  # workers + the loop
        assert "softsensor_health" in str(scrape_metrics(m.port))
        time.sleep(1.0)
        assert m.expired >= 1  # the ones still open at the deadline were closed
        assert m.answer("/other").code == 404
    finally:
        for s in slow:
            s.close()
        asyncio.run(m.stop())
