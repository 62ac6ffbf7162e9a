"""A daemon with every operator output enabled (Modbus registers, Prometheus metrics, the live
page, OPC UA) against the simulated PLC, each read by its real client on 127.0.0.1 (issue 13)."""

from __future__ import annotations

import asyncio
import json
import urllib.request

import numpy as np
from clients import modbus_read, opcua_read, register_float, scrape_metrics
from daemon_harness import daemon_settings, published, serving_plc

from softsensor.bus.zenoh_bus import free_port
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.service.daemon import Daemon


def test_the_daemon_serves_its_estimates_on_every_output(tmp_path):
    """A daemon with every output table enabled, against the simulated PLC: after some ticks
    the registers, the metrics, the OPC UA items and the page's API hold the last estimate it
    published, and its start line names what it serves."""
    day = simulate_day(load_plant_config(), 2.0, 5)
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n[outputs.modbus]\nenabled = true\n"
                 "port = 0\n[outputs.prometheus]\nenabled = true\nport = 0\n"
                 "[outputs.web]\nenabled = true\nport = 0\n"
                 f"[outputs.opcua]\nenabled = true\nport = {free_port()}\n")
    cfg = load_plant_config(p)
    settings = daemon_settings(tmp_path, int(day.scans.index[0]), cfg, record=False)
    got: dict = {}

    async def main() -> None:
        async with serving_plc(day) as (_, tagmap):
            daemon = Daemon(cfg, settings, tagmap=tagmap)
            estimates = published(daemon, "estimate")
            stop, up = asyncio.Event(), []
            task = asyncio.create_task(daemon.run(stop, ready=up.append))
            try:
                deadline = asyncio.get_running_loop().time() + 60
                while len(estimates) < 3:
                    assert asyncio.get_running_loop().time() < deadline and not task.done()
                    await asyncio.sleep(0.05)
                got["info"] = up[0]
                outputs = daemon.outputs
                got["registers"], _, _ = await modbus_read(outputs["modbus"].port)
                got["metrics"] = await asyncio.to_thread(scrape_metrics,
                                                         outputs["prometheus"].port)
                got["opcua"] = await opcua_read(outputs["opcua"].endpoint,
                                                ["moisture_out", "health"])
                url = f"http://127.0.0.1:{outputs['web'].port}/api/latest.json"
                got["web"] = json.loads(await asyncio.to_thread(
                    lambda: urllib.request.urlopen(url, timeout=5).read()))
                got["last"] = estimates[-1]
                got["n"] = len(estimates)
            finally:
                stop.set()
                await asyncio.wait_for(task, 30)

    asyncio.run(asyncio.wait_for(main(), 120))
    info, w, m, last = got["info"], got["registers"], got["metrics"], got["last"]
    assert any(o.startswith("modbus://127.0.0.1:") for o in info.outputs), info.outputs
    assert any(o.endswith("/metrics") for o in info.outputs), info.outputs
    # the registers hold an estimate the daemon published (the last one, or one tick before)
    assert w[15] >= 3 and (w[12] << 16 | w[13]) * 10**9 <= last.time_ns
    if (w[12] << 16 | w[13]) * 10**9 == last.time_ns:
        assert register_float(w, "moisture_out") == np.float32(last.moisture_out)
    assert 0.0 < register_float(w, "moisture_out") < 1.0 and w[14] in (0, 1)
    assert m["softsensor_ticks_total"] >= 3 and m["softsensor_scans_total"] > 0
    assert m["softsensor_poller_read_failures_total"] == 0
    assert 0.0 < m["softsensor_moisture_out_kg_per_kg"] < 1.0
    assert m["softsensor_tick_duration_seconds_count"] >= 3
    assert any(o.startswith("http://127.0.0.1:") and o.endswith("/") for o in info.outputs)
    assert 0.0 < got["opcua"]["moisture_out"][0] < 1.0, got["opcua"]
    assert got["opcua"]["health"][0] in ("ok", "degraded")
    assert any(o.startswith("opc.tcp://127.0.0.1:") for o in info.outputs), info.outputs
    web = got["web"]["estimate"]
    assert web["window_end_ns"] <= last.time_ns and 0.0 < web["moisture_out"] < 1.0
