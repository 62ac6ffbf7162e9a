"""The virtual plant's verbs (``softsensor/apps/virtual_plant.py``): ``plant-server`` refuses a
busy port before it simulates and says what it does while it simulates (issues 24 and 30);
``simulate`` refuses bad input in one line."""

from __future__ import annotations

import re
import socket
import subprocess
import sys

import pytest


def test_plant_server_refuses_a_busy_port_before_it_simulates():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "softsensor.cli", "plant-server", "--port",
                            str(port), "--hours", "48"], capture_output=True, text=True,
                           timeout=60)
    assert r.returncode == 2, (r.returncode, r.stderr[-1000:])
    # before it simulates: the one line is all it said, no "simulating ..." line first (a
    # wall-time bound here depended on the machine's load, issue 49)
    assert r.stderr.strip().splitlines() == [
        f"softsensor: plant-server cannot listen on 127.0.0.1:{port}: Address already in use "
        "(another --port?)"], r.stderr


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


@pytest.mark.parametrize("args,needle", [
    (["--effect", "smoke"], "unknown effect 'smoke'"),
    (["--hours", "-1"], "--hours must be in"),
    (["--config", "/nonexistent/plant.toml"], "no such config file"),
])
def test_cli_bad_input_is_one_line(tmp_path, args, needle):
    r = subprocess.run([sys.executable, "-m", "softsensor.cli", "simulate", "--plant", "model",
                        "--hours", "1", *args, "--out", str(tmp_path / "x.mcap")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
