"""How the verbs speak (softsensor/apps/verb_output.py): one human line on stderr, JSON only where
``--json`` says, outputs replaced whole, unwritable targets refused before the work."""

from __future__ import annotations

import json
import time

from paths import REPO

from softsensor.apps.verb_output import write_json
from softsensor.cli import main as cli_main


def test_json_goes_only_where_asked(tmp_path, capsys):
    write_json({"a": 1.5, "nan": float("nan")}, None)
    assert capsys.readouterr() == ("", "")
    write_json({"a": 1.5}, "-")
    assert json.loads(capsys.readouterr().out) == {"a": 1.5}
    write_json({"a": 2}, tmp_path / "x.json")
    assert json.loads((tmp_path / "x.json").read_text()) == {"a": 2}
    assert capsys.readouterr() == ("", "")


def test_calibrate_refuses_a_folder_as_json_at_once(tmp_path, capsys):
    day = REPO / "replay" / "demo-day.mcap"
    rc = cli_main(["calibrate", str(day), "--out", str(tmp_path / "p.toml"),
                   "--json", str(tmp_path)])
    err = capsys.readouterr().err.strip()
    # before any trial: the one line is all it said (no progress line, no "calibrate: ..."
    # phase); a wall-time bound here depended on the machine's load (issue 49)
    assert rc == 2 and "is a directory" in err and "\n" not in err


def test_replay_progress_is_throttled(capsys, monkeypatch):
    from softsensor.apps import streaming

    clock = iter([0.0, 1.0, 6.0, 7.0, 12.5])
    monkeypatch.setattr(streaming.time, "monotonic", lambda: next(clock))
    show = streaming._every(5.0)  # reads the clock once (0.0)
    for k in range(4):  # at 1.0 (quiet), 6.0 (a line), 7.0 (quiet), 12.5 (a line)
        show(1767571200 * 10**9 + (k + 1) * 600 * 10**9, k + 1)
    lines = capsys.readouterr().err.splitlines()
    assert lines == ["replay: 2 ticks, at 2026-01-05T00:20:00Z ...",
                     "replay: 4 ticks, at 2026-01-05T00:40:00Z ..."]


def test_sigterm_during_replay_keeps_the_previous_out(tmp_path):
    """Issue 14: SIGTERM during ``replay`` destroyed the previous ``--out``."""
    import signal
    import subprocess
    import sys
    import time

    root = REPO
    out = tmp_path / "est.mcap"
    out.write_bytes(b"the earlier replay")
    proc = subprocess.Popen([sys.executable, "-m", "softsensor.cli", "replay",
                             str(root / "replay" / "demo-day.mcap"), "--out", str(out)],
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list(tmp_path.glob(".est.mcap.*.tmp.mcap")):  # streaming has begun
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-1000:]
    assert out.read_bytes() == b"the earlier replay"
    assert [p.name for p in tmp_path.iterdir()] == ["est.mcap"], err[-500:]
    assert "Traceback" not in err


def test_sigterm_into_calibrate_answers_as_ctrl_c(tmp_path):
    """Issue 40: SIGTERM ended ``calibrate`` by the signal (143, no message) while ``replay``
    answered 130 with a line; one rule for every verb now: 130, one line, no ``--out``."""
    import signal
    import subprocess
    import sys
    import threading

    out = tmp_path / "p.toml"
    proc = subprocess.Popen([sys.executable, "-m", "softsensor.cli", "calibrate",
                             str(REPO / "replay" / "demo-day.mcap"), "--trials", "500",
                             "--out", str(out)], stderr=subprocess.PIPE, text=True)
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(iter(lambda: proc.stderr.read(1), "")))
    reader.start()
    deadline = time.monotonic() + 120
    while "trial/s" not in "".join(err):  # the study runs (past loading and compiling)
        assert proc.poll() is None and time.monotonic() < deadline, "".join(err)[-1000:]
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=30)
    reader.join(10)
    proc.stderr.close()
    text = "".join(err)
    assert proc.returncode == 130, text[-1000:]
    assert text.strip().splitlines()[-1] == "softsensor: interrupted", text[-1000:]
    assert "Traceback" not in text and not out.exists()
