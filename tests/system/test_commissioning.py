"""Commissioning day (issue 30): what an engineer meets setting the soft sensor up beside a
real dryer, each checked with the real client where there is one."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import re
import socket
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from clients import chromium_dom, scrape_metrics
from paths import REPO

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.presentation.display import DisplaySettings
from softsensor.service.logs import KeyValueFormatter

# --- item 1: a refused lab file reaches the health, the counters, the page and the metrics ---


def test_a_refused_lab_file_reaches_health_metrics_page_and_status_line(tmp_path, caplog):
    """Every LIMS file refused by the lab folder: the daemon's health names the refusal at
    once, the status line and Prometheus count it, ``/api/latest.json`` and the page (read by
    headless Chromium) show it, and health turns degraded once no lab result was accepted for
    ``service.max_lab_silence_h`` of plant time."""
    from softsensor.ingest.tagmap import load_tagmap
    from softsensor.plant.plc_feed import PlantFeed
    from softsensor.plant.plc_server import PlcServer
    from softsensor.plant.simulator import simulate_day
    from softsensor.service.daemon import Daemon
    from softsensor.service.settings import service_settings

    scale = 240.0
    day = simulate_day(load_plant_config(), 2.0, 5)
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n[outputs.prometheus]\nenabled = true\n"
                 "port = 0\n[outputs.web]\nenabled = true\nport = 0\n")
    cfg = load_plant_config(p)
    lab_dir = tmp_path / "lab"
    settings = service_settings(cfg).with_overrides(
        data_dir=str(tmp_path / "rec"), checkpoint=str(tmp_path / "ckpt.json"),
        lab_dir=str(lab_dir), lab_settle_s=0.0, status_every_s=0.3,
        zenoh_listen=["tcp/127.0.0.1:0"], time_scale=scale, max_lab_silence_h=0.5,
        clock_start=str(int(day.scans.index[0])), record=False)
    got: dict = {}
    caplog.set_level(logging.INFO, logger="softsensor.service.daemon")

    async def main() -> None:
        feed = PlantFeed(day, loop=True)
        tm = load_tagmap()
        plc = PlcServer(tm, feed.next_values, port=0, period_s=10.0 / scale)
        await plc.start()
        daemon = Daemon(cfg, settings, tagmap=tm.with_endpoint("127.0.0.1", plc.port))
        health: list = []
        hook = daemon._on_output

        def spy(out):
            hook(out)
            if out.kind == "health":
                health.append(out.to_body())

        daemon._on_output = spy
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
            while not any(h.get("last_lab_refusal") for h in health):
                assert loop.time() < deadline and not task.done()
                await asyncio.sleep(0.05)
            got["refused"] = next(h for h in health if h.get("last_lab_refusal"))
            while not (health[-1]["lab_status"] == "degraded"
                       and "web" in daemon.outputs and daemon.outputs["web"].snapshot()[0]):
                assert loop.time() < deadline and not task.done()
                await asyncio.sleep(0.05)
            got["degraded"] = health[-1]
            await asyncio.sleep(0.4)  # a status line after the refusal
            outputs = daemon.outputs
            got["metrics"] = await asyncio.to_thread(scrape_metrics, outputs["prometheus"].port)
            base = f"http://127.0.0.1:{outputs['web'].port}/"
            got["latest"] = json.loads(await asyncio.to_thread(
                lambda: urllib.request.urlopen(base + "api/latest.json", timeout=5).read()))
            got["dom"] = await asyncio.to_thread(chromium_dom, base)
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
            await plc.stop()

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


# --- item 2: a busy Modbus port is one line and exit 2; -v shows the traceback it promises ---


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


def test_verbose_before_or_after_the_verb_prints_the_traceback(tmp_path, capsys, monkeypatch):
    """An unexpected error says "--verbose shows where": with ``-v`` before or after the verb
    the traceback is printed, also under ``run``, whose key=value log lines kept only the
    exception's name."""
    from softsensor.cli import main
    from softsensor.service.daemon import Daemon

    async def broken(self, stop, ready=None):
        raise ValueError("a bug deep inside")

    monkeypatch.setattr(Daemon, "run", broken)
    base = ["--no-record", "--lab-dir", str(tmp_path / "lab"), "--checkpoint",
            str(tmp_path / "ckpt.json")]
    for argv in (["run", *base], ["-v", "run", *base], ["run", "-v", *base],
                 ["run", *base, "--verbose"]):
        capsys.readouterr()
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert err.rstrip("\n").splitlines()[-1] == (
            "softsensor run: unexpected ValueError: a bug deep inside (this is a bug; "
            "--verbose shows where)"), err
        shown = "Traceback (most recent call last)" in err and "in broken" in err
        assert shown == (argv != ["run", *base]), (argv, err)


# --- item 3: a wrong unit inside the physical range is held against the estimator's envelope ---

EXAMPLE = REPO / "replay"


def _kg_per_h_map(tmp_path: Path, lab: str | None = None) -> Path:
    """The shipped example's map with the fibre flow (really t/h) declared kg/h."""
    text = (EXAMPLE / "historian-map.toml").read_text()
    head, sep, rest = text.partition("[signals.m_fiber]")
    rest = rest.replace('unit = "t/h"', 'unit = "kg/h"', 1)
    if lab is not None:
        rest = rest.split("[lab]")[0] + lab
    p = tmp_path / "map.toml"
    p.write_text(head + sep + rest)
    return p


def test_a_flow_in_t_per_h_declared_kg_per_h_is_refused_naming_the_unit(tmp_path, capsys):
    """0.006 kg/s lies inside the import's physical range of m_fiber but far below what the
    estimator accepts: the import refuses it in one line naming the signal, the unit declared
    and the likely right one (it wrote the day, exit 0, and replay then blamed
    solver.scan_period); the preview names it too, and the config's [plausibility] table is
    the envelope held against."""
    from softsensor.cli import main

    hmap = _kg_per_h_map(tmp_path)
    scans = str(EXAMPLE / "historian-example.csv")
    out = tmp_path / "day.mcap"
    assert main(["import", "--map", str(hmap), "--scans", scans, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert re.search(r"WI-4713\.PV \(signals\.m_fiber\) read as 'kg/h': 719 of 719 values "
                     r"outside the operating envelope 2\.\.10 kg/s .* in 't/h' they fall inside "
                     r"\(median 5\.86\d kg/s\): set signals\.m_fiber\.unit = 't/h'", err), err
    assert not out.exists()
    assert main(["import", "--map", str(hmap), "--scans", scans, "--preview", "2"]) == 0
    shown = capsys.readouterr().out
    row = next(line for line in shown.splitlines() if line.startswith("m_fiber"))
    assert re.search(r"-0\.5\.\.20\s+2\.\.10\s+100%", row), row
    assert "SUSPECT unit, the import refuses it:" in shown and "'t/h'" in shown
    # a plant that really runs there says so in its config, and the import takes it
    cfg = tmp_path / "plant.toml"
    cfg.write_text(default_config_path().read_text()
                   + "\n[plausibility.m_fiber]\nlow = 0.001\nhigh = 10.0\n")
    assert main(["import", "--map", str(hmap), "--scans", scans, "--out", str(out),
                 "--config", str(cfg)]) == 0
    assert out.exists()


def test_a_replay_that_estimates_nothing_names_the_refused_input(tmp_path):
    """A day whose fibre flow the plausibility limits refuse (imported before the check, or
    recorded elsewhere): replay says that m_fiber was refused, outside 2..10, instead of
    blaming solver.scan_period."""
    from softsensor.apps.import_export import _read_scans, write_imported_day
    from softsensor.ingest.historian_map import load_map
    from softsensor.service.offline_replay import replay_to_file

    hmap = load_map(_kg_per_h_map(tmp_path))
    day = tmp_path / "day.mcap"
    write_imported_day(day, _read_scans(hmap, EXAMPLE / "historian-example.csv", True), None)
    summary = replay_to_file(day, tmp_path / "est.mcap", load_plant_config(),
                             report_truth=False)
    kind, why = summary.problem()
    assert kind == "error" and summary.stale_ticks == summary.ticks > 0, why
    assert "scan_period" not in why, why
    assert re.search(r"the plausibility limits refused the inputs: m_fiber: \d+ values refused "
                     r"\(.*first: 0\.00\d+ outside 2\.\.10\)\) \(is the unit of m_fiber right\?",
                     why), why


def test_the_lab_preview_shows_values_as_read_and_converted_and_a_suspect_header(tmp_path,
                                                                                 capsys):
    """A LIMS column headed "Moisture %wb" holding fractions, declared kg/kg on a dry basis
    (it imported 11 % low without a word): the preview shows each result as read and as
    converted and names the basis to set; the import warns."""
    from softsensor.cli import main

    lab = ('[lab]\nsample_time_column = "Sample Time"\navailable_column = "Result Time"\n'
           'moisture_column = "Moisture %wb"\nsample_id_column = "Sample ID"\n'
           'unit = "kg/kg"\nbasis = "dry"\ndayfirst = true\n')
    hmap = _kg_per_h_map(tmp_path, lab).read_text().replace(
        '[signals.m_fiber]\ncolumn = "WI-4713.PV"\nunit = "kg/h"',
        '[signals.m_fiber]\ncolumn = "WI-4713.PV"\nunit = "t/h"')
    (tmp_path / "map.toml").write_text(hmap)
    lims = tmp_path / "lims.csv"
    lims.write_text("Sample ID,Sample Time,Result Time,Moisture %wb\n"
                    "S1,05/01/2026 01:31:15,05/01/2026 02:00:49,0.0996\n"
                    "S2,05/01/2026 05:20:42,05/01/2026 06:39:17,0.1044\n")
    args = ["import", "--map", str(tmp_path / "map.toml"), "--scans",
            str(EXAMPLE / "historian-example.csv"), "--lab", str(lims)]
    assert main([*args, "--preview", "2"]) == 0
    shown = capsys.readouterr().out
    assert re.search(r"S1\s+2026-01-05T01:31:15\+01:00\s+0\.0996\s+0\.0996\s+9\.06", shown), shown
    assert ("SUSPECT lab unit: the lab column 'Moisture %wb' says wet basis but lab.basis is "
            "\"dry\" (set lab.basis = \"wet\")") in shown
    assert "says % but lab.unit is 'kg/kg' and its values look like fractions" in shown
    assert main([*args, "--out", str(tmp_path / "day.mcap")]) == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "set lab.basis = \"wet\"" in err


# --- item 6: the command line ---


def _verbs() -> dict[str, argparse.ArgumentParser]:
    from softsensor.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _readme_exit_codes() -> dict[str, set[int]]:
    """Per verb, the exit statuses the documented table gives (docs/user-guide/commands.md;
    a '-' cell: none)."""
    text = (REPO / "docs" / "user-guide" / "commands.md").read_text()
    table = text.split("| verb | 0 | 1 | 2 | 130 |")[1].split("\n\n")[0]
    out: dict[str, set[int]] = {}
    for row in table.strip().splitlines()[1:]:
        cells = [c.strip() for c in row.strip("|").split("|")]
        codes = {code for code, cell in zip((0, 1, 2, 130), cells[1:], strict=True)
                 if cell != "-"}
        for verb in re.findall(r"`([a-z-]+)`", cells[0]):
            out[verb] = codes
    return out


def test_every_verb_describes_itself_lists_its_exit_codes_and_helps_every_option(capsys):
    """10 of 12 verbs had no description in --help, none listed its exit codes, four options
    had no help, --params showed as PARAMS.toml and PARAMS, and --fit-fraction named an
    internal constant."""
    from softsensor.cli import EXIT_CODES, main

    readme = _readme_exit_codes()
    verbs = _verbs()
    assert set(verbs) == set(readme) == set(EXIT_CODES)
    metavars: dict[str, set[str]] = {}
    for name, verb in verbs.items():
        assert verb.description and verb.description[0].isupper(), name
        assert set(EXIT_CODES[name]) == readme[name], name
        for action in verb._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and "DEFAULT_" not in action.help, (name, action.dest)
            for flag in action.option_strings:
                if action.nargs != 0:
                    metavars.setdefault(flag, set()).add(str(action.metavar or action.dest))
        with pytest.raises(SystemExit) as done:
            main([name, "--help"])
        assert done.value.code == 0
        shown = capsys.readouterr().out
        assert "exit status:" in shown, name
        for code in EXIT_CODES[name]:
            assert re.search(rf"^  {code}\s+\S", shown, re.M), (name, code)
    for flag in ("--params", "--config"):
        assert len(metavars[flag]) == 1, (flag, metavars[flag])
    assert metavars["--params"] == {"PARAMS.toml"}


def test_long_verbs_take_quiet_and_design_speaks_plant_units():
    verbs = _verbs()
    for name in ("calibrate", "diagnose", "replay", "design", "plant-server"):
        assert any("--quiet" in a.option_strings for a in verbs[name]._actions), name
    design = {a.dest: a.help for a in verbs["design"]._actions}
    assert "[°C]" in design["T_sp_band"] and "[t/h]" in design["m_air_band"]
    assert "[t/h per min]" in design["m_air_rate"]


def test_a_missing_offline_package_exits_1_as_the_readme_says(tmp_path, capsys, monkeypatch):
    import importlib.util

    from softsensor.cli import main

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "optuna" else real(name, *a))
    assert main(["validate", str(tmp_path / "day.mcap"), "--params",
                 str(tmp_path / "p.toml")]) == 1
    err = capsys.readouterr().err
    assert err == ("softsensor: validate needs the package optuna, which this install leaves "
                   "out: pip install 'softsensor[offline]'\n")


def test_health_imports_only_its_own_verbs():
    """``softsensor health`` took 2.9 to 5.8 s here against a daemon that answered at once:
    building the parser imported every verb module, the calibration's SciPy among them. A
    command line naming its verb imports that verb's module alone."""
    code = ("import sys, time; from softsensor.cli import build_parser; "
            "t = time.perf_counter(); p = build_parser(['health']); "
            "print(time.perf_counter() - t, 'scipy.stats' in sys.modules, "
            "'softsensor.apps.calibrate' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    seconds, scipy, calibrate = r.stdout.split()
    assert (scipy, calibrate) == ("False", "False"), r.stdout
    assert float(seconds) < 2.0


# --- item 5: the demo's start is readable ---


def _free() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_plant_server_says_what_it_does_while_it_simulates(capsys, monkeypatch):
    """``plant-server`` said nothing for 20 to 40 s while it simulated: it now says what it
    simulates, that it still does every HEARTBEAT_S, and how long it took; --quiet keeps only
    the serving line."""
    from softsensor.apps import virtual_plant
    from softsensor.cli import main

    monkeypatch.setattr(virtual_plant, "HEARTBEAT_S", 0.02)
    argv = ["plant-server", "--port", "0", "--hours", "0.5", "--once", "--speed", "1e5"]
    assert main(argv) == 0
    out = capsys.readouterr()
    lines = out.err.splitlines()
    assert lines[0] == ("plant-server: simulating 0.5 h of plant independent (plant seed 0), "
                        "seed 0; serving starts when it is done"), lines
    assert any(line.startswith("plant-server: still simulating (") for line in lines), lines
    assert re.search(r"^plant-server: simulated 181 scans and \d+ lab results in [\d.]+ s$",
                     out.err, re.M), out.err
    assert "plant-server: serving " in out.out
    assert main([*argv, "--quiet"]) == 0
    out = capsys.readouterr()
    assert "simulat" not in out.err and "plant-server: serving " in out.out


# --- item 8: a Spanish or German spreadsheet export (';' and ',') ---


def _european(tmp_path: Path) -> Path:
    """The shipped example written as a Spanish Excel saves it: ';' between fields, ','
    as the decimal mark."""
    out = tmp_path / "export-es.csv"
    lines = []
    for line in (EXAMPLE / "historian-example.csv").read_text().splitlines():
        cells = [re.sub(r"^(-?\d+)\.(\d+)$", r"\1,\2", c) for c in line.split(",")]
        lines.append(";".join(cells))
    out.write_text("\n".join(lines) + "\n")
    return out


def test_a_semicolon_export_with_decimal_commas_names_delimiter_and_decimal(tmp_path, capsys):
    from softsensor.cli import main

    export = _european(tmp_path)
    text = (EXAMPLE / "historian-map.toml").read_text()
    cases = [(text, r"the header is one column holding ';': set source\.delimiter = ';', "
                    r"and source\.decimal = ','"),
             (text.replace("[source]\n", "[source]\ndelimiter = \";\"\n"),
              r"row 1: TI-4711\.PV value '209,85' is written with a decimal comma: set "
              r"source\.decimal = ','")]
    for map_text, pattern in cases:
        (tmp_path / "map.toml").write_text(map_text)
        assert main(["import", "--map", str(tmp_path / "map.toml"), "--scans", str(export),
                     "--preview"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and re.search(pattern, err), err
        assert "bad_values" not in err and "skip_rows" not in err, err
    (tmp_path / "map.toml").write_text(
        text.replace("[source]\n", "[source]\ndelimiter = \";\"\ndecimal = \",\"\n"))
    assert main(["import", "--map", str(tmp_path / "map.toml"), "--scans", str(export),
                 "--out", str(tmp_path / "day.mcap")]) == 0


def test_the_lab_folder_reads_its_lab_tables_delimiter_and_names_it(tmp_path):
    """The daemon's lab folder split every CSV at ',' whatever [lab] delimiter said; a ';'
    file is read with delimiter ';', and without it refused naming lab.delimiter."""
    from softsensor.ingest.historian_map import LabMap
    from softsensor.ingest.lab_input import LabFolderWatcher, LabInput

    got: list = []
    body = ("sample_time;moisture;sample_id\n2026-01-05T08:00:00Z;9,957;L1\n")
    for delimiter in (";", ","):
        folder = tmp_path / f"lab{delimiter == ';'}"
        folder.mkdir()
        (folder / "lims.csv").write_text(body)
        lab = LabMap(sample_time_column="sample_time", moisture_column="moisture", unit="%",
                     basis="wet", sample_id_column="sample_id", delimiter=delimiter,
                     decimal=",")
        clock = lambda: 1_767_603_600 * 10**9  # noqa: E731 - 2026-01-05T09:00Z
        w = LabFolderWatcher(folder, LabInput(got.append, clock=clock), lab_map=lab,
                             settle_s=0.0)
        report = w.poll_once(now=2e9)
        if delimiter == ";":
            assert [r.sample_id for r in report.accepted] == ["L1"], report.reasons
            assert got[0].moisture_out == pytest.approx(0.09957 / (1 - 0.09957))
        else:
            assert "set lab.delimiter = ';'" in report.reasons[0], report.reasons


def test_the_daemon_follows_the_virtual_plcs_clock(tmp_path):
    """The demo's two clocks: started after plant-server (the natural order), a daemon whose
    clock started at the day's first scan ran behind the plant by the delay times the speed,
    and refused every lab file as sampled after it arrived. The virtual PLC serves its plant
    clock (mbpoll reads it), and ``--clock-start plc`` starts the daemon's clock there."""
    from softsensor.ingest.tagmap import load_tagmap
    from softsensor.plant.plc_feed import PlantFeed
    from softsensor.plant.plc_server import PlcServer
    from softsensor.plant.simulator import simulate_day
    from softsensor.service.daemon import Daemon
    from softsensor.service.settings import service_settings

    scale = 240.0
    day = simulate_day(load_plant_config(), 2.0, 5)
    cfg = load_plant_config()
    settings = service_settings(cfg).with_overrides(
        data_dir=str(tmp_path / "rec"), checkpoint=str(tmp_path / "ckpt.json"),
        lab_dir=str(tmp_path / "lab"), zenoh_listen=["tcp/127.0.0.1:0"], time_scale=scale,
        clock_start="plc", record=False)
    got: dict = {}

    async def main() -> None:
        feed = PlantFeed(day, loop=True)
        tm = load_tagmap()
        plc = PlcServer(tm, feed.next_values, port=0, period_s=10.0 / scale,
                        clock=lambda: feed.plant_time_ns)
        await plc.start()
        try:
            await asyncio.sleep(2.0)  # the plant runs on: 480 plant seconds
            r = await asyncio.to_thread(subprocess.run, [
                "mbpoll", "-m", "tcp", "-a", "1", "-0", "-r", "20", "-c", "1", "-t", "3:int",
                "-B", "-1", "-p", str(plc.port), "127.0.0.1"],
                capture_output=True, text=True, timeout=30)
            got["mbpoll"] = (r.stdout, feed.plant_time_ns)
            daemon = Daemon(cfg, settings, tagmap=tm.with_endpoint("127.0.0.1", plc.port))
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
        finally:
            await plc.stop()

    asyncio.run(asyncio.wait_for(main(), 150))
    text, plant_ns = got["mbpoll"]
    served = int(re.search(r"\[20\]:\s+(-?\d+)", text).group(1))
    assert abs(served * 10**9 - plant_ns) <= 60 * 10**9, text  # one read, a scan apart
    assert plant_ns - int(day.scans.index[0]) > 300 * 10**9  # the plant ran on before
    daemon_ns, plant_ns = got["clocks"]
    # one clock: apart by the PLC's whole seconds and a few scans, not by the start delay
    assert abs(daemon_ns - plant_ns) < 60 * 10**9, (daemon_ns - plant_ns) / 1e9


# --- item 7 (part): Prometheus names, and the band clipped at bone dry ---


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


def test_the_pages_outlet_axis_stops_at_zero_for_a_wide_start_up_band(tmp_path):
    """Headless Chromium reads the page of a start-up (an outlet moisture of 0.03 kg/kg with
    a standard deviation as large): the band and the axis stop at 0 %, not below."""
    from softsensor.outputs.settings import WebSettings
    from softsensor.outputs.web import LivePage

    t0 = 1_767_571_200 * 10**9
    page = LivePage(WebSettings(enabled=True, port=0), DisplaySettings(moisture_basis="wet"),
                    clock=lambda: t0 + 13 * 600 * 10**9)
    for k in range(12):
        page.on_estimate(Estimate.from_body({
            "window_end_ns": t0 + (k + 1) * 600 * 10**9,
            "moisture_out": 0.03, "moisture_out_std": 0.03 - 0.002 * k, "moisture_in": 1.0,
            "moisture_in_std": 0.05, "status": "ok", "T_dryer_out_model": 348.0,
            "T_dryer_out_measured": 348.2, "T_cyclone_out_model": 345.0,
            "T_cyclone_out_measured": 345.1}))
    asyncio.run(page.start())
    try:
        dom = chromium_dom(f"http://127.0.0.1:{page.port}/")
    finally:
        asyncio.run(page.stop())
    outlet = re.search(r"<svg[^>]*id=\"outlet\".*?</svg>", dom, re.S).group(0)
    ticks = [float(v) for v in re.findall(r"class=\"tick-y\"[^>]*>([^<]+)<", outlet)]
    assert ticks and min(ticks) >= 0.0, ticks
