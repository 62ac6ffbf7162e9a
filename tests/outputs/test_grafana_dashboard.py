"""The Grafana dashboard in ``docs/grafana/softsensor.json`` (issue 24, item 6) reads the
daemon's metrics: every metric its queries name is one the daemon's ``/metrics`` exports
(scraped over HTTP and parsed by prometheus_client), every query selects the dashboard's
``site`` and ``dryer`` (the unit name; issue 30: the label ``unit`` meant a unit of measure
to anyone reading metrics), and the variables are read from a metric that exists."""

from __future__ import annotations

import asyncio
import json
import re
import urllib.request

from paths import REPO
from prometheus_client.parser import text_string_to_metric_families

from softsensor.estimate import Estimate
from softsensor.outputs.metrics import DaemonMetrics
from softsensor.outputs.settings import MetricsSettings
from softsensor.plantconfig import load_plant_config
from softsensor.presentation.display import DisplaySettings
from softsensor.service.daemon import Daemon
from softsensor.service.settings import service_settings

DASHBOARD = REPO / "docs" / "grafana" / "softsensor.json"
BODY = {"moisture_out": 0.1, "moisture_out_std": 0.004, "moisture_in": 1.0,
        "moisture_in_std": 0.02, "status": "ok", "T_dryer_out_measured": 348.0,
        "T_dryer_out_model": 348.2, "T_cyclone_out_measured": 345.0,
        "T_cyclone_out_model": 345.1}


def _exported() -> set[str]:
    """Every sample name the daemon's metrics endpoint serves, with the daemon's counters."""
    cfg = load_plant_config()
    names = Daemon(cfg, service_settings(cfg))._counters()
    counters = {name: (doc, lambda: 1.0) for name, (doc, _fn) in names.items()}
    m = DaemonMetrics(MetricsSettings(enabled=True, port=0), counters, unit="dryer1",
                      display=DisplaySettings(), tick_seconds=lambda: 0.1)
    asyncio.run(m.start())
    try:
        m.on_estimate(Estimate.from_body({**BODY, "window_end_ns": 1_767_607_800 * 10**9}))
        text = urllib.request.urlopen(f"http://127.0.0.1:{m.port}/metrics",
                                      timeout=5).read().decode()
    finally:
        asyncio.run(m.stop())
    return {s.name for fam in text_string_to_metric_families(text) for s in fam.samples}


def _queries(doc: dict) -> list[str]:
    exprs = [t["expr"] for p in doc["panels"] for t in p.get("targets", [])]
    exprs += [v["query"]["query"] for v in doc["templating"]["list"] if v["type"] == "query"]
    return exprs


def test_every_query_names_an_exported_metric_and_selects_site_and_dryer():
    doc = json.loads(DASHBOARD.read_text(encoding="utf-8"))
    exported = _exported()
    queries = _queries(doc)
    assert len(queries) >= 15
    used = {m for q in queries for m in re.findall(r"\b(softsensor_[a-z0-9_]+)\b", q)}
    assert used and not used - exported, sorted(used - exported)
    # the moisture in % wet basis, its band and limits, and the temperatures are all read
    for name in ("softsensor_moisture_out_wet_basis_percent",
                 "softsensor_moisture_out_band_wet_basis_percent",
                 "softsensor_moisture_out_limit_wet_basis_percent",
                 "softsensor_outlet_temperature_celsius", "softsensor_health"):
        assert name in used, name
    for p in doc["panels"]:
        for t in p["targets"]:
            assert 'site="$site"' in t["expr"] and 'dryer="$dryer"' in t["expr"], t["expr"]
            assert t["datasource"]["uid"] == "${DS_PROMETHEUS}"
    ids = [p["id"] for p in doc["panels"]]
    assert len(ids) == len(set(ids))
    names = {v["name"] for v in doc["templating"]["list"]}
    assert {"DS_PROMETHEUS", "site", "dryer"} <= names
