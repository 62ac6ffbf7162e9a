"""Commissioning day (issue 30), end to end: what an engineer meets setting the soft sensor up
beside a real dryer where it takes the running daemon or several verbs to show, each checked with
the real client where there is one. The findings of one module stand with that module's tests:
the command line's help, exit codes and tracebacks in ``tests/test_cli.py``, the import's unit
and delimiter checks in ``tests/ingest/test_envelope.py`` and ``tests/ingest/test_cells.py``, the
lab folder's delimiter in ``tests/ingest/test_lab_input.py``, ``plant-server``'s progress in
``tests/apps/test_virtual_plant.py``, the PLC's clock read by mbpoll in
``tests/plant/test_plc_server.py``, the Prometheus names in ``tests/outputs/test_metrics.py``
and the page's axis in ``tests/outputs/test_web.py``."""

from __future__ import annotations

import asyncio
import json
import logging
import re
import socket
import subprocess
import sys
import urllib.request

import pytest
from clients import chromium_dom, scrape_metrics
from daemon_harness import daemon_settings, published, serving_plc
from historian_files import kg_per_h_map
from paths import REPLAY

from softsensor.errors import ConfigError
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.presentation.display import DisplaySettings
from softsensor.service.daemon import Daemon
from softsensor.service.logs import KeyValueFormatter

# --- item 1: a refused lab file reaches the health, the counters, the page and the metrics ---


@pytest.mark.chromium
def test_a_refused_lab_file_reaches_health_metrics_page_and_status_line(tmp_path, caplog):
    """Every LIMS file refused by the lab folder: the daemon's health names the refusal at
    once, the status line and Prometheus count it, ``/api/latest.json`` and the page (read by
    headless Chromium) show it, and health turns degraded once no lab result was accepted for
    ``service.max_lab_silence_h`` of plant time."""
    day = simulate_day(load_plant_config(), 2.0, 5)
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n[outputs.prometheus]\nenabled = true\n"
                 "port = 0\n[outputs.web]\nenabled = true\nport = 0\n")
    cfg = load_plant_config(p)
    lab_dir = tmp_path / "lab"
    settings = daemon_settings(tmp_path, int(day.scans.index[0]), cfg, lab_settle_s=0.0,
                               status_every_s=0.3, max_lab_silence_h=0.5, record=False)
    got: dict = {}
    caplog.set_level(logging.INFO, logger="softsensor.service.daemon")

    async def main() -> None:
        async with serving_plc(day) as (_, tagmap):
            daemon = Daemon(cfg, settings, tagmap=tagmap)
            health = published(daemon, "health")
            stop = asyncio.Event()
            task = asyncio.create_task(daemon.run(stop))
            loop = asyncio.get_running_loop()
            try:
                deadline = loop.time() + 90
                while daemon.info is None or not health:
                    assert loop.time() < deadline and not task.done()
                    await asyncio.sleep(0.05)
                # the LIMS writes the moisture with a decimal comma: every file refused
                lab_dir.mkdir(exist_ok=True)
                (lab_dir / "lims-0800.csv").write_text(
                    "sample_time,moisture_out,sample_id\n2026-01-05T08:00:00Z,\"0,104\",L1\n")
                while not any(h.to_body().get("last_lab_refusal") for h in health):
                    assert loop.time() < deadline and not task.done()
                    await asyncio.sleep(0.05)
                got["refused"] = next(h.to_body() for h in health
                                      if h.to_body().get("last_lab_refusal"))
                while not (health[-1].to_body()["lab_status"] == "degraded"
                           and "web" in daemon.outputs and daemon.outputs["web"].snapshot()[0]):
                    assert loop.time() < deadline and not task.done()
                    await asyncio.sleep(0.05)
                got["degraded"] = health[-1].to_body()
                await asyncio.sleep(0.4)  # a status line after the refusal
                outputs = daemon.outputs
                got["metrics"] = await asyncio.to_thread(scrape_metrics,
                                                         outputs["prometheus"].port)
                base = f"http://127.0.0.1:{outputs['web'].port}/"
                got["latest"] = json.loads(await asyncio.to_thread(
                    lambda: urllib.request.urlopen(base + "api/latest.json", timeout=5).read()))
                got["dom"] = await asyncio.to_thread(chromium_dom, base)
            finally:
                stop.set()
                await asyncio.wait_for(task, 30)

    asyncio.run(asyncio.wait_for(main(), 150))
    refused = got["refused"]
    assert refused["labs_refused"] == 1 and refused["lab_files_refused"] == 1
    assert refused["last_lab_refusal"].startswith("lab file refused: lims-0800.csv")
    assert (lab_dir / "rejected" / "lims-0800.csv").exists()
    degraded = got["degraded"]
    assert degraded["status"] == "degraded", degraded
    assert "no lab result accepted for" in degraded["detail"]
    assert "(service.max_lab_silence_h 0.5)" in degraded["detail"]
    assert "last lab refusal: lab file refused: lims-0800.csv" in degraded["detail"]
    m = got["metrics"]
    assert m["softsensor_labs_refused_total"] == 1.0
    assert m["softsensor_lab_files_refused_total"] == 1.0
    assert m["softsensor_health[('status', 'degraded')]"] == 1.0
    health = got["latest"]["health"]
    assert health["last_lab_refusal"].startswith("lab file refused: lims-0800.csv")
    assert health["status"] == "degraded"
    dom = got["dom"]
    assert 'id="last-lab-refusal"' in dom and "lims-0800.csv" in dom, dom[:3000]
    assert "no lab result was taken for hours" in dom
    fmt = KeyValueFormatter()
    status = [fmt.format(r) for r in caplog.records if r.getMessage() == "status"]
    assert any("labs_refused=1 lab_files_refused=1" in line
               and "last_lab_refusal=" in line and "lims-0800.csv" in line
               for line in status), status[-1:]


# --- item 2: a busy Modbus port is one line and exit 2 ---


def _busy_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen(1)
    return s, s.getsockname()[1]


def test_a_busy_modbus_output_port_is_one_line_and_exit_2(tmp_path):
    """``[outputs.modbus]`` on a port in use: ``softsensor run`` exits 2 with one line naming
    the table and the system's reason (pymodbus raised a bare ``RuntimeError``, exit 1), before
    it polls the PLC."""
    from softsensor.outputs.modbus_server import EstimateModbusServer
    from softsensor.outputs.settings import ModbusOutputSettings

    busy, port = _busy_port()
    with busy:
        server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=port),
                                      DisplaySettings())
        with pytest.raises(ConfigError, match=rf"^outputs\.modbus: cannot listen on "
                                              rf"127\.0\.0\.1:{port}: Address already in use$"):
            asyncio.run(server.start())
        cfg = tmp_path / "plant.toml"
        cfg.write_text(default_config_path().read_text()
                       + f"\n[outputs.modbus]\nenabled = true\nport = {port}\n")
        r = subprocess.run([sys.executable, "-m", "softsensor.cli", "run", "--config", str(cfg),
                            "--no-record", "--listen", "tcp/127.0.0.1:0", "--plc",
                            f"127.0.0.1:{port}", "--lab-dir", str(tmp_path / "lab"),
                            "--checkpoint", str(tmp_path / "ckpt.json")],
                           capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert r.returncode == 2, r.stderr[-3000:]
    last = r.stderr.rstrip("\n").splitlines()[-1]
    assert last == (f"softsensor: outputs.modbus: cannot listen on 127.0.0.1:{port}: Address "
                    f"already in use"), r.stderr[-3000:]
    assert "Traceback" not in r.stderr and "poller" not in r.stderr  # stopped before polling


# --- item 3: a wrong unit inside the physical range is held against the estimator's envelope ---


def test_a_replay_that_estimates_nothing_names_the_refused_input(tmp_path):
    """A day whose fibre flow the plausibility limits refuse (imported before the check, or
    recorded elsewhere): replay says that m_fiber was refused, outside 2..10, instead of
    blaming solver.scan_period."""
    from softsensor.apps.import_export import _read_scans, write_imported_day
    from softsensor.ingest.historian_map import load_map
    from softsensor.service.offline_replay import replay_to_file

    hmap = load_map(kg_per_h_map(tmp_path))
    day = tmp_path / "day.mcap"
    write_imported_day(day, _read_scans(hmap, REPLAY / "historian-example.csv", True), None)
    summary = replay_to_file(day, tmp_path / "est.mcap", load_plant_config(),
                             report_truth=False)
    kind, why = summary.problem()
    assert kind == "error" and summary.stale_ticks == summary.ticks > 0, why
    assert "scan_period" not in why, why
    assert re.search(r"the plausibility limits refused the inputs: m_fiber: \d+ values refused "
                     r"\(.*first: 0\.00\d+ outside 2\.\.10\)\) \(is the unit of m_fiber right\?",
                     why), why


# --- the demo's two clocks: the daemon starts its clock on the PLC's ---


def test_the_daemon_follows_the_virtual_plcs_clock(tmp_path):
    """The demo's two clocks: started after plant-server (the natural order), a daemon whose
    clock started at the day's first scan ran behind the plant by the delay times the speed,
    and refused every lab file as sampled after it arrived. The virtual PLC serves its plant
    clock (``tests/plant/test_plc_server.py``: mbpoll reads it), and ``--clock-start plc``
    starts the daemon's clock there."""
    day = simulate_day(load_plant_config(), 2.0, 5)
    cfg = load_plant_config()
    settings = daemon_settings(tmp_path, int(day.scans.index[0]), cfg, clock_start="plc",
                               record=False)
    got: dict = {}

    async def main() -> None:
        async with serving_plc(day, clock=True) as (feed, tagmap):
            await asyncio.sleep(2.0)  # the plant runs on: 480 plant seconds
            got["plant_before"] = feed.plant_time_ns
            daemon = Daemon(cfg, settings, tagmap=tagmap)
            stop = asyncio.Event()
            task = asyncio.create_task(daemon.run(stop))
            deadline = asyncio.get_running_loop().time() + 90
            while daemon.info is None:
                assert asyncio.get_running_loop().time() < deadline and not task.done()
                await asyncio.sleep(0.05)
            await asyncio.sleep(1.0)
            got["clocks"] = (daemon.clock.now_ns(), feed.plant_time_ns)
            stop.set()
            await asyncio.wait_for(task, 30)

    asyncio.run(asyncio.wait_for(main(), 150))
    # the plant ran on before the daemon started
    assert got["plant_before"] - int(day.scans.index[0]) > 300 * 10**9
    daemon_ns, plant_ns = got["clocks"]
    # one clock: apart by the PLC's whole seconds and a few scans, not by the start delay
    assert abs(daemon_ns - plant_ns) < 60 * 10**9, (daemon_ns - plant_ns) / 1e9


