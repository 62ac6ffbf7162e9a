"""The daemon in-process against the simulated PLC, accelerated: estimates, lab drop, PLC
outage and reconnect, and the same estimates from ``replay`` of what it recorded.

The virtual plant serves a simulated day through :class:`PlcServer` 240 times faster than real
time and the daemon's clock runs at the same speed (``service.time_scale``), so a 600 s window
lasts 2.5 s. Everything listens on 127.0.0.1 with ports chosen at run time; every wait has a
deadline.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
from pathlib import Path

import pytest
from paths import REPO

from softsensor.bus.zenoh_bus import Publisher, free_port, open_session, subscribe, wait_for_peers
from softsensor.ingest.tagmap import load_tagmap
from softsensor.plant.plc_feed import PlantFeed
from softsensor.plant.plc_server import PlcServer
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.service.checkpoint import CheckpointStore
from softsensor.service.daemon import Daemon, DaemonInfo
from softsensor.service.offline_replay import replay_to_file
from softsensor.service.settings import service_settings
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB

SCALE = 240.0
WINDOW_NS = 600 * 10**9


@pytest.fixture(scope="module")
def day():
    return simulate_day(load_plant_config(), 6.0, 11)


async def until(cond, timeout: float, what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not cond():
        if loop.time() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        await asyncio.sleep(0.02)


def _settings(tmp_path: Path, clock_start: int):
    return service_settings(load_plant_config()).with_overrides(
        data_dir=str(tmp_path / "rec"), checkpoint=str(tmp_path / "state" / "ckpt.json"),
        lab_dir=str(tmp_path / "lab"), zenoh_listen=["tcp/127.0.0.1:0"], time_scale=SCALE,
        clock_start=str(clock_start), lab_settle_s=0.0, status_every_s=1.0,
        tick_delay_s=60.0)  # 0.25 s wall at 240x: labs and ticks never race


def test_daemon_estimates_survives_a_plc_outage_and_replays_identically(day, tmp_path):
    cfg = load_plant_config()
    settings = _settings(tmp_path, int(day.scans.index[0]))
    seen: list = []
    outcome: dict = {}

    async def main() -> None:
        feed = PlantFeed(day, loop=True)
        tm = load_tagmap()
        plc = PlcServer(tm, feed.next_values, port=0, period_s=10.0 / SCALE)
        await plc.start()
        daemon = Daemon(cfg, settings, tagmap=tm.with_endpoint("127.0.0.1", plc.port))
        stop = asyncio.Event()
        up: list[DaemonInfo] = []
        task = asyncio.create_task(daemon.run(stop, ready=up.append))
        try:
            await until(lambda: up or task.done(), 20, "the daemon to start")
            (info,) = up
            assert info.endpoints[0].startswith("tcp/127.0.0.1:") and not info.resumed
            with open_session(port=None, connect=info.endpoints) as outside:
                assert wait_for_peers(outside, timeout=5)
                sub = subscribe(outside, seen.append, kinds=("estimate", "health", "lab"))
                svc = daemon.worker.service
                await until(lambda: svc.stats.ticks >= 2, 30, "two ticks")

                # a lab result dropped into the folder, sampled 15 plant-minutes ago
                last = next(m.body for m in reversed(seen) if m.kind == "estimate")
                sample = daemon.clock.now_ns() - 900 * 10**9
                lab = {"sample_time_ns": sample, "sample_id": "T-1",
                       "moisture_out": round(last["moisture_out"] + 0.005, 4)}
                (tmp_path / "lab" / ".T-1.tmp").write_text(json.dumps(lab))
                (tmp_path / "lab" / ".T-1.tmp").rename(tmp_path / "lab" / "T-1.json")
                await until(lambda: any(m.kind == "estimate" and m.body["lab_updated"]
                                        for m in seen), 20, "an estimate with the lab")

                # the PLC goes away for a while, then comes back on the same port
                stale0 = svc.stats.stale_ticks
                outcome["outage_from"] = daemon.clock.now_ns()
                await plc.stop()
                await until(lambda: svc.stats.stale_ticks >= stale0 + 2, 30, "stale ticks")
                await plc.start()
                outcome["outage_to"] = daemon.clock.now_ns()
                ticks0 = svc.stats.ticks
                await until(lambda: svc.stats.ticks >= ticks0 + 3, 30, "ticks after restart")
                outcome["connects"] = daemon.poller.stats.connects
                sub.close()
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
            outcome["stats"] = daemon.worker.service.stats
            await plc.stop()
            outcome["writes"] = plc.write_requests

    asyncio.run(asyncio.wait_for(main(), 150))

    # the PLC was only read, and the poller reconnected after the restart
    assert outcome["writes"] == 0 and outcome["connects"] >= 2
    estimates = [m for m in seen if m.kind == "estimate"]
    ends = [m.time_ns for m in estimates]
    assert all(b - a == WINDOW_NS for a, b in zip(ends, ends[1:], strict=False))
    for m in estimates:
        for key in ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std",
                    "T_dryer_out_model", "T_cyclone_out_model", "lab_updated"):
            assert key in m.body, key
    # the outage is stale, on the bus and in the recording; estimation goes on around it
    during = [m.body for m in estimates
              if outcome["outage_from"] + WINDOW_NS <= m.time_ns <= outcome["outage_to"]]
    assert during and all(b["stale"] for b in during)
    after = [m.body for m in estimates if m.time_ns > outcome["outage_to"] + WINDOW_NS]
    assert after and not after[-1]["stale"] and math.isfinite(after[-1]["moisture_in"])
    health = [m.body for m in seen if m.kind == "health"]
    assert any(h["status"] == "stale" and "not_connected" in h["detail"] for h in health)
    assert health[-1]["status"] in ("ok", "degraded") and health[-1]["input_status"] == "ok"
    # the lab went from the folder onto the bus, into the filter and into processed/
    assert [m.body["sample_id"] for m in seen if m.kind == "lab"] == ["T-1"]
    assert (tmp_path / "lab" / "processed" / "T-1.json").exists()
    assert outcome["stats"].labs_accepted == 1 and outcome["stats"].labs_refused == 0

    # everything was recorded; the checkpoint holds the last state
    (path,) = (tmp_path / "rec").glob("dryer1-*.mcap")
    rec = read_day(path)
    live = {t: b for t, b in rec.topic(TOPIC_ESTIMATE)}
    assert all(live.get(m.time_ns) == {k: v for k, v in m.body.items() if k != "time_ns"}
               for m in estimates)
    assert rec.labs["sample_id"].tolist() == ["T-1"] and rec.topic(TOPIC_HEALTH)
    assert [b["sample_id"] for _, b in rec.topic(TOPIC_LAB)] == ["T-1"]
    doc = CheckpointStore(settings.checkpoint).load()
    assert doc["service"]["stats"]["ticks"] == outcome["stats"].ticks == len(live)

    # replaying the recorded day gives the very same estimates
    summary = replay_to_file(path, tmp_path / "replayed.mcap", cfg, settings=settings)
    replayed = dict(summary.estimates)
    assert set(live) <= set(replayed)
    assert {t: replayed[t] for t in live} == live
    assert summary.lab_updates >= 1 and summary.stale_ticks >= 2


def test_daemon_as_a_router_client_without_a_plc(tmp_path):
    """Client mode through a router (the config's optional router endpoint): with no PLC the
    daemon keeps running and says why on the health key; a lab result published on the bus by
    another client (a LIMS) reaches the service and the recording."""
    cfg = load_plant_config()
    router_port = free_port()
    dead_port = free_port()  # nothing listens here
    router_ep = f"tcp/127.0.0.1:{router_port}"
    settings = _settings(tmp_path, 1_767_571_200 * 10**9).with_overrides(
        zenoh_mode="client", zenoh_connect=[router_ep], plc_host="127.0.0.1",
        plc_port=dead_port)
    seen: list = []
    stats: dict = {}

    async def main() -> None:
        with open_session(mode="router", port=router_port) as _router, \
                open_session(mode="client", connect=[router_ep]) as lims:
            daemon = Daemon(cfg, settings)
            stop = asyncio.Event()
            task = asyncio.create_task(daemon.run(stop))
            try:
                await until(lambda: daemon.worker is not None or task.done(), 20, "start")
                assert daemon.info is not None and daemon.info.endpoints == []
                sub = subscribe(lims, seen.append, kinds=("health",))
                await until(lambda: any("not_connected" in m.body["detail"] for m in seen),
                            20, "a health message naming the missing PLC")
                with Publisher(lims) as pub:
                    assert await asyncio.to_thread(pub.wait_matched, ("lab",), 5.0)
                    sample = daemon.clock.now_ns() - 600 * 10**9
                    pub.put("lab", {"sample_time_ns": sample, "moisture_out": 0.11,
                                    "sample_id": "LIMS-1"}, daemon.clock.now_ns())
                    await until(lambda: daemon.worker.service.stats.labs_received == 1, 10,
                                "the lab result")
                sub.close()
            finally:
                stop.set()
                await asyncio.wait_for(task, 30)
            stats["poller"] = daemon.poller.stats

    asyncio.run(asyncio.wait_for(main(), 90))
    health = [m.body for m in seen]
    assert health[-1]["status"] == "stale" and health[-1]["input_status"] == "degraded"
    assert stats["poller"].connects == 0 and stats["poller"].scans > 0
    (path,) = (tmp_path / "rec").glob("dryer1-*.mcap")
    rec = read_day(path)
    assert rec.labs["sample_id"].tolist() == ["LIMS-1"]
    assert rec.scans[list(rec.scans.columns)].isna().all().all()  # nothing was read


def test_run_refuses_bad_input_in_one_line(tmp_path, capsys):
    from softsensor.cli import main as cli_main
    from softsensor.service.estimator_service import EstimatorService
    from softsensor.service.estimators import make_estimator

    bad = tmp_path / "bad.toml"
    bad.write_text(default_config_path().read_text() + '\n[service]\nlisten = "x"\n')
    ckpt = tmp_path / "ckpt.json"
    CheckpointStore(ckpt).save(
        EstimatorService(make_estimator("ukf", load_plant_config())).checkpoint(),
        saved_at_ns=1, unit="dryer1")
    cases = [
        (["--config", str(bad)], r"bad\.toml: service\.listen is not a known key"),
        (["--plc", "localhost"], r"--plc must look like HOST:PORT"),
        (["--time-scale", "-2"], r"command line: service\.time_scale must be >= 0\.01"),
        (["--checkpoint", str(ckpt), "--estimator", "openloop", "--no-record"],
         r"ckpt\.json: written by estimator 'ukf', this run uses 'openloop' \(use "
         r"--no-resume"),
    ]
    for args, pattern in cases:
        capsys.readouterr()
        assert cli_main(["run", "--lab-dir", str(tmp_path / "lab"), *args]) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and re.search(pattern, err), err


def test_a_copied_config_folder_runs_with_its_own_tag_map(tmp_path):
    """Issue 13: a copied ``config/`` with an edited tag map was silently run with the
    packaged one. The tag map beside the config file is used, a relative ``tagmap`` key is
    taken relative to the config file, and one that does not exist is an error naming it."""
    from softsensor.errors import ConfigError
    from softsensor.plantconfig import load_plant_config
    from softsensor.service.daemon import daemon_tagmap
    from softsensor.service.settings import service_settings

    root = REPO / "config"
    site = tmp_path / "site"
    site.mkdir()
    (site / "dryer1.toml").write_text((root / "dryer1.toml").read_text())
    (site / "tagmap_dryer1.toml").write_text(
        (root / "tagmap_dryer1.toml").read_text().replace('port = 502', 'port = 15020', 1))
    settings = service_settings(load_plant_config(site / "dryer1.toml"))
    assert Path(settings.tagmap) == site / "tagmap_dryer1.toml"
    assert daemon_tagmap(settings).modbus.port == 15020
    # a relative key, from another working directory
    (site / "maps").mkdir()
    (site / "tagmap_dryer1.toml").rename(site / "maps" / "plc.toml")
    cfg = site / "dryer1.toml"
    cfg.write_text(cfg.read_text() + '\n[service]\ntagmap = "maps/plc.toml"\n')
    settings = service_settings(load_plant_config(cfg))
    assert daemon_tagmap(settings).modbus.port == 15020
    cfg.write_text(cfg.read_text().replace("maps/plc.toml", "maps/none.toml"))
    with pytest.raises(ConfigError, match="none.toml"):
        daemon_tagmap(service_settings(load_plant_config(cfg)))
    # the packaged config keeps the packaged tag map
    assert daemon_tagmap(service_settings(load_plant_config())).modbus.port == 502


def test_run_takes_the_tag_map_beside_the_config_also_with_params(tmp_path):
    """``softsensor run --config site/dryer1.toml --params P`` ran with the packaged tag map:
    the parameters' file renamed the config's source, so the folder was not found."""
    import argparse

    from softsensor.apps.streaming import run_settings
    from softsensor.service.daemon import daemon_tagmap

    root = REPO / "config"
    site = tmp_path / "site"
    site.mkdir()
    (site / "dryer1.toml").write_text((root / "dryer1.toml").read_text())
    (site / "tagmap_dryer1.toml").write_text(
        (root / "tagmap_dryer1.toml").read_text().replace('port = 502', 'port = 15021', 1))
    params = tmp_path / "params.toml"
    params.write_text("[parameters.mult_D]\nvalue = 0.9\n")
    names = ("unit tagmap plc data_dir checkpoint lab_dir mode listen connect estimator "
             "time_scale clock_start log_format").split()
    args = argparse.Namespace(config=str(site / "dryer1.toml"), params=str(params),
                              no_record=False, **dict.fromkeys(names))
    base, cfg, settings = run_settings(args)
    assert cfg.parameters["mult_D"].value == 0.9 and base.source == str(site / "dryer1.toml")
    assert daemon_tagmap(settings).modbus.port == 15021


_IMPORTS = """
import sys
import softsensor.cli, softsensor.service.daemon, softsensor.outputs.opcua_server
import softsensor.outputs.web, softsensor.outputs.metrics, softsensor.outputs.modbus_server
print(sorted(m for m in ("pandas", "pyarrow", "matplotlib", "scipy.stats", "scipy.linalg")
             if m in sys.modules))
"""


def test_the_daemon_with_every_output_imports_no_table_or_plot_library():
    """Issue 49 (fifth probe): resident memory 383 MB at rest with all four outputs. The
    daemon's modules and its outputs' must not load pandas and pyarrow (62 MB resident): the
    lab files' cell converter loaded them with its delimiter hint at import although the lab
    files load pandas only with the first file. (The estimator's lab regression still loads
    them when the service is built, and the first lab file does: issue 49's report.)"""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _IMPORTS], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "[]", r.stdout


@pytest.mark.slow
def test_daemon_publishes_the_advice_and_never_writes_to_the_plc(day, tmp_path):
    """[advisor] enabled: a real daemon polling a real PLC server publishes one advice body
    per estimate on softsensor/<unit>/advice (read by a raw Zenoh subscriber), and the PLC
    sees no write."""
    from softsensor.plantconfig import PARAMETER_NAMES, load_parameters, with_table

    ident = tmp_path / "ident.json"
    ident.write_text(json.dumps({"verdicts": {n: {"relative_se": 0.05} for n in PARAMETER_NAMES},
                                 "correlation": [[float(i == j) for j in range(7)]
                                                 for i in range(7)]}))
    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "independent_plant_params.toml"
    cfg = with_table(load_parameters(str(fixture), load_plant_config()), "advisor",
                     {"enabled": True, "identify": str(ident)})
    settings = _settings(tmp_path, int(day.scans.index[0]))
    advice: list = []
    outcome: dict = {}

    async def main() -> None:
        feed = PlantFeed(day, loop=True)
        tm = load_tagmap()
        plc = PlcServer(tm, feed.next_values, port=0, period_s=10.0 / SCALE)
        await plc.start()
        daemon = Daemon(cfg, settings, tagmap=tm.with_endpoint("127.0.0.1", plc.port))
        stop = asyncio.Event()
        up: list[DaemonInfo] = []
        task = asyncio.create_task(daemon.run(stop, ready=up.append))
        try:
            await until(lambda: up or task.done(), 20, "the daemon to start")
            with open_session(port=None, connect=up[0].endpoints) as outside:
                assert wait_for_peers(outside, timeout=5)
                sub = outside.declare_subscriber(
                    "softsensor/dryer1/advice",
                    lambda s: advice.append(json.loads(s.payload.to_bytes())))
                await until(lambda: len(advice) >= 2, 60, "two advice bodies")
                sub.undeclare()
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
            await plc.stop()
            outcome["writes"] = plc.write_requests

    asyncio.run(asyncio.wait_for(main(), 150))
    assert outcome["writes"] == 0
    for body in advice:
        assert isinstance(body["advised"], bool) and body["reason"]
        assert "\n" not in body["reason"] and body["time_ns"] % WINDOW_NS == 0
