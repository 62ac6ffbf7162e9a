"""Estimates where operators look (issue 13): the Modbus register server and the Prometheus
metrics, each read by real clients on 127.0.0.1 (pymodbus and ``mbpoll``; urllib and
``prometheus_client``'s parser), and both run by a daemon against the simulated PLC."""

from __future__ import annotations

import asyncio
import json
import math
import re
import shlex
import shutil
import struct
import subprocess
import threading
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from clients import opcua_read, scrape_metrics
from paths import REPO
from pymodbus.client import AsyncModbusTcpClient

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.outputs.metrics import DaemonMetrics
from softsensor.outputs.modbus_server import (
    N_REGISTERS,
    REGISTERS,
    EstimateModbusServer,
    estimate_registers,
)
from softsensor.outputs.settings import MetricsSettings, ModbusOutputSettings, output_settings
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.presentation.display import DisplaySettings, moisture_pct

BODY = {"moisture_out": 0.1034, "moisture_out_std": 0.0042, "moisture_in": 1.0312,
        "moisture_in_std": 0.021, "status": "degraded", "lab_updated": True}
T_NS = 1_767_607_800 * 10**9  # 2026-01-05T10:10:00Z
ESTIMATE = Estimate.from_body({**BODY, "window_end_ns": T_NS})


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def f32(words: list[int], name: str) -> float:
    a = REGISTERS[name][0]
    return struct.unpack(">f", struct.pack(">HH", *words[a:a + 2]))[0]


def test_register_layout_encodes_every_field():
    w = estimate_registers(BODY, T_NS, 7, DisplaySettings(moisture_basis="wet"))
    assert len(w) == N_REGISTERS and all(0 <= x < 65536 for x in w)
    for k in ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std"):
        assert f32(w, k) == pytest.approx(BODY[k], rel=1e-7)
    assert f32(w, "moisture_out_pct") == pytest.approx(100 * 0.1034 / 1.1034, rel=1e-6)
    assert (w[12] << 16 | w[13]) == T_NS // 10**9
    assert w[14] == 1 and w[15] == 7 and w[16] == 1
    empty = estimate_registers({"status": "stale"}, T_NS, 8, DisplaySettings())
    assert math.isnan(f32(empty, "moisture_out")) and empty[14] == 2
    assert estimate_registers({}, 0, 0, DisplaySettings())[14] == 3  # nothing estimated yet


class _Loop:
    """An event loop on a thread, as the daemon's."""

    def __enter__(self):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        return self

    def run(self, coro, timeout: float = 20.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def __exit__(self, *exc):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


async def _read(port: int, write: bool = False):
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
    await client.connect()
    try:
        rr = await client.read_input_registers(0, count=N_REGISTERS, device_id=1)
        assert not rr.isError(), rr
        wr = await client.write_register(0, 5, device_id=1) if write else None
        hr = await client.read_holding_registers(0, count=1, device_id=1) if write else None
        return rr.registers, wr, hr
    finally:
        client.close()


def test_modbus_server_serves_the_estimate_to_pymodbus_and_mbpoll_and_refuses_writes():
    server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0),
                                  DisplaySettings(moisture_basis="dry"))
    with _Loop() as lp:
        lp.run(server.start())
        try:
            before, _, _ = lp.run(_read(server.port))
            assert before[14] == 3 and math.isnan(f32(before, "moisture_out"))
            server.on_estimate(ESTIMATE)  # from this (another) thread, as the estimator's
            words = None
            for _ in range(100):  # bounded: the store is handed to the server's loop
                words, wr, hr = lp.run(_read(server.port, write=True))
                if words[15] == 1:
                    break
            assert words[15] == 1 and wr.isError() and hr.isError()
            assert f32(words, "moisture_out") == np.float32(BODY["moisture_out"])
            assert f32(words, "moisture_in_pct") == np.float32(moisture_pct(1.0312, "dry"))
            assert server.refused >= 2
            server.on_health(Health.from_body({"status": "stale"}, T_NS))
            for _ in range(100):
                words, _, _ = lp.run(_read(server.port))
                if words[14] == 2:
                    break
            assert words[14] == 2
            mbpoll = shutil.which("mbpoll")
            if mbpoll is None:
                pytest.skip("mbpoll is not installed (apt install mbpoll)")
            r = subprocess.run([mbpoll, "-m", "tcp", "-a", "1", "-0", "-r", "0", "-c", "4",
                                "-t", "3:float", "-B", "-1", "-p", str(server.port),
                                "127.0.0.1"], capture_output=True, text=True, timeout=20)
            got = {int(a): float(v) for a, v in
                   re.findall(r"^\[(\d+)\]:\s+(\S+)\s*$", r.stdout, re.M)}
            assert got[0] == pytest.approx(BODY["moisture_out"], rel=1e-6), r.stdout
            assert got[2] == pytest.approx(BODY["moisture_out_std"], rel=1e-6), r.stdout
        finally:
            lp.run(server.stop())


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


def test_output_tables_are_validated(tmp_path):
    def cfg(text: str):
        p = tmp_path / "plant.toml"
        p.write_text(default_config_path().read_text() + "\n" + text)
        return load_plant_config(p)

    o = output_settings(load_plant_config())
    assert not o.modbus.enabled and not o.prometheus.enabled and o.modbus.host == "127.0.0.1"
    o = output_settings(cfg("[outputs.modbus]\nenabled = true\nport = 1503\n"))
    assert o.modbus.enabled and o.modbus.port == 1503
    with pytest.raises(ConfigError, match=r"outputs\.modbus\.port must be"):
        output_settings(cfg("[outputs.modbus]\nport = 70000\n"))
    with pytest.raises(ConfigError, match=r"outputs\.scada is not a known key \(known: modbus, "):
        output_settings(cfg("[outputs.scada]\nenabled = true\n"))
    with pytest.raises(ConfigError, match=r"outputs\.prometheus\.colour is not a known key"):
        output_settings(cfg("[outputs.prometheus]\ncolour = 1\n"))


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


def test_the_daemon_serves_its_estimates_on_both_outputs(tmp_path):
    """A daemon with both tables enabled, against the simulated PLC: after some ticks the
    registers and the metrics hold the last estimate it published, and its start line names
    what it serves."""
    from softsensor.ingest.tagmap import load_tagmap
    from softsensor.plant.plc_feed import PlantFeed
    from softsensor.plant.plc_server import PlcServer
    from softsensor.plant.simulator import simulate_day
    from softsensor.service.daemon import Daemon
    from softsensor.service.settings import service_settings

    scale = 240.0
    day = simulate_day(load_plant_config(), 2.0, 5)
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n[outputs.modbus]\nenabled = true\n"
                 "port = 0\n[outputs.prometheus]\nenabled = true\nport = 0\n"
                 "[outputs.web]\nenabled = true\nport = 0\n"
                 f"[outputs.opcua]\nenabled = true\nport = {_free_port()}\n")
    cfg = load_plant_config(p)
    settings = service_settings(cfg).with_overrides(
        data_dir=str(tmp_path / "rec"), checkpoint=str(tmp_path / "ckpt.json"),
        lab_dir=str(tmp_path / "lab"),
        zenoh_listen=["tcp/127.0.0.1:0"], time_scale=scale,
        clock_start=str(int(day.scans.index[0])), record=False)
    got: dict = {}

    async def main() -> None:
        feed = PlantFeed(day, loop=True)
        tm = load_tagmap()
        plc = PlcServer(tm, feed.next_values, port=0, period_s=10.0 / scale)
        await plc.start()
        daemon = Daemon(cfg, settings, tagmap=tm.with_endpoint("127.0.0.1", plc.port))
        published: list = []
        hook = daemon._on_output

        def spy(out):
            hook(out)
            if out.kind == "estimate":
                published.append(out)

        daemon._on_output = spy
        stop, up = asyncio.Event(), []
        task = asyncio.create_task(daemon.run(stop, ready=up.append))
        try:
            deadline = asyncio.get_running_loop().time() + 60
            while len(published) < 3:
                assert asyncio.get_running_loop().time() < deadline and not task.done()
                await asyncio.sleep(0.05)
            got["info"] = up[0]
            got["registers"], _, _ = await _read(daemon.outputs["modbus"].port)
            outputs = daemon.outputs
            got["metrics"] = await asyncio.to_thread(scrape_metrics, outputs["prometheus"].port)
            got["opcua"] = await opcua_read(outputs["opcua"].endpoint, ["moisture_out", "health"])
            url = f"http://127.0.0.1:{outputs['web'].port}/api/latest.json"
            got["web"] = json.loads(await asyncio.to_thread(
                lambda: urllib.request.urlopen(url, timeout=5).read()))
            got["last"] = published[-1]
            got["n"] = len(published)
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
            await plc.stop()

    asyncio.run(asyncio.wait_for(main(), 120))
    info, w, m, last = got["info"], got["registers"], got["metrics"], got["last"]
    assert any(o.startswith("modbus://127.0.0.1:") for o in info.outputs), info.outputs
    assert any(o.endswith("/metrics") for o in info.outputs), info.outputs
    # the registers hold an estimate the daemon published (the last one, or one tick before)
    assert w[15] >= 3 and (w[12] << 16 | w[13]) * 10**9 <= last.time_ns
    if (w[12] << 16 | w[13]) * 10**9 == last.time_ns:
        assert f32(w, "moisture_out") == np.float32(last.moisture_out)
    assert 0.0 < f32(w, "moisture_out") < 1.0 and w[14] in (0, 1)
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


# ---------------------------------------------------------------------------------------------
# The ``mbpoll`` command lines the user guide (docs/user-guide/operator-screens.md) and
# docs/interface.md give a plant engineer, run as
# written (only the port and host replaced by the test's) against the Modbus output (issue 24,
# item 4: the documented command asked for 24 registers where 17 exist).

DOCS = (REPO / "docs" / "user-guide" / "operator-screens.md", REPO / "docs" / "interface.md")


def documented_commands(path: Path) -> list[str]:
    """Every line of a fenced code block that starts with ``mbpoll``."""
    text = path.read_text(encoding="utf-8")
    blocks = re.findall(r"^```[a-z]*\n(.*?)^```", text, re.M | re.S)
    return [line.split("#")[0].strip() for b in blocks for line in b.splitlines()
            if line.strip().startswith("mbpoll ")]


def _at(command: str, port: int) -> list[str]:
    """The documented command with its port and host replaced (nothing else touched)."""
    argv = shlex.split(command)
    assert argv[0] == "mbpoll" and "-p" in argv, command
    argv[argv.index("-p") + 1] = str(port)
    argv[-1] = "127.0.0.1"
    return argv


def test_both_documents_give_the_same_mbpoll_commands():
    readme, interface = (documented_commands(p) for p in DOCS)
    assert readme and readme == interface, (readme, interface)


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed "
                    "(apt-get install mbpoll)")
def test_the_documented_mbpoll_commands_read_every_register():
    server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0),
                                  DisplaySettings(moisture_basis="wet"))
    with _Loop() as lp:
        lp.run(server.start())
        try:
            server.on_estimate(ESTIMATE)
            for _ in range(100):  # bounded: the store is handed to the server's loop
                words, _, _ = lp.run(_read(server.port))
                if words[15] == 1:
                    break
            got: dict[int, float] = {}
            for command in documented_commands(DOCS[1]):
                r = subprocess.run(_at(command, server.port), capture_output=True, text=True,
                                   timeout=20)
                assert r.returncode == 0 and "Illegal" not in r.stdout + r.stderr, \
                    (command, r.stdout[-500:], r.stderr[-500:])
                got.update({int(a): float(v) for a, v in
                            re.findall(r"^\[(\d+)\]:\s+(\S+)\s*$", r.stdout, re.M)})
        finally:
            lp.run(server.stop())
    f32 = [struct.unpack(">f", struct.pack(">HH", *words[a:a + 2]))[0] for a in range(0, 12, 2)]
    for i, value in enumerate(f32):
        assert got[2 * i] == pytest.approx(value, rel=1e-6), got
    assert got[12] == T_NS // 10**9
    assert (got[14], got[15], got[16]) == (1, 1, 1)  # degraded, first estimate, lab applied
    assert max(got) < N_REGISTERS
