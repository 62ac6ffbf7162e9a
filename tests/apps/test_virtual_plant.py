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


def test_simulate_start_and_days_write_a_consecutive_history(tmp_path, capsys):
    """Issue 49: every simulated day started 2026-01-05, so no consecutive history could be
    made for ``calibrate``. ``--start`` sets the first log time; ``--days N`` writes N records
    of ``--hours`` into a folder, record i with seed ``--seed + i`` from ``--start + i x
    --hours``, named by their UTC start so that they sort in time order, and ``replay`` takes
    them as one stream (it refuses days out of time order)."""
    from softsensor.cli import main
    from softsensor.recording.mcap_day import read_day

    h = 3600 * 10**9
    start = 1_772_344_800 * 10**9  # 2026-03-01T06:00:00Z
    one = tmp_path / "one.mcap"
    assert main(["simulate", "--plant", "model", "--hours", "1", "--seed", "4", "--start",
                 "2026-03-01T06:00:00Z", "--out", str(one)]) == 0
    assert "from 2026-03-01T06:00:00Z" in capsys.readouterr().err
    assert int(read_day(one).scans.index[0]) == start
    folder = tmp_path / "history"
    assert main(["simulate", "--plant", "model", "--hours", "2", "--seed", "4", "--days", "3",
                 "--start", "2026-03-01T06:00:00Z", "--out", str(folder)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"wrote 3 consecutive records of 2 h to {folder}"), err
    names = sorted(p.name for p in folder.iterdir())
    assert names == ["2026-03-01T060000Z.mcap", "2026-03-01T080000Z.mcap",
                     "2026-03-01T100000Z.mcap"]
    days = [read_day(folder / n) for n in names]
    for i, d in enumerate(days):
        t = d.scans.index.to_numpy()
        # each record but the last is cut where the next begins (no overlap: replay and
        # calibrate take them as one history); the last ends with the scan at its end
        end = start + (i + 1) * 2 * h
        assert t[0] == start + i * 2 * h and (t[-1] < end if i < 2 else t[-1] == end)
        assert (d.labs["log_time_ns"] < end).all() or i == 2
    # one seed a record: the days differ (not one day copied three times)
    assert not days[0].scans["T_dryer_out"].to_numpy()[:100].tolist() == \
        days[1].scans["T_dryer_out"].to_numpy()[:100].tolist()
    assert main(["replay", *[str(folder / n) for n in names], "--out",
                 str(tmp_path / "est.mcap"), "--quiet"]) == 0
    assert "37 ticks" in capsys.readouterr().err


@pytest.mark.parametrize("args,needle", [
    (["--days", "0"], "--days must be >= 1, got 0"),
    (["--start", "yesterday"], "--start must be ns since the epoch or an ISO-8601 time"),
])
def test_simulate_bad_start_or_days_is_one_line(tmp_path, capsys, args, needle):
    from softsensor.cli import main

    assert main(["simulate", "--hours", "1", *args, "--out", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err
    assert not (tmp_path / "x.mcap").exists()


def test_simulate_days_into_a_file_is_refused(tmp_path, capsys):
    from softsensor.cli import main

    (tmp_path / "f.mcap").write_bytes(b"x")
    assert main(["simulate", "--plant", "model", "--hours", "1", "--days", "2", "--out",
                 str(tmp_path / "f.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a folder for one file a record" in err[0], err
