"""``softsensor run`` as a subprocess: SIGKILL mid-day, restart from the checkpoint, SIGTERM.

The simulated PLC runs in a thread of the test process, 240 times faster than real time; the
daemon's clock runs at the same speed (``[service] time_scale`` in a config file written
here). The daemon is killed outright after a few ticks, started again with the same command,
and must continue with the window after the last one it checkpointed; the day file it was
writing when killed must replay (``--allow-truncated``) and fail in one line without the flag.
"""

from __future__ import annotations

import asyncio
import json
import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from softsensor.cli import main as cli_main
from softsensor.errors import IngestError
from softsensor.ingest.tagmap import load_tagmap
from softsensor.plant.plc_feed import PlantFeed
from softsensor.plant.plc_server import PlcServer
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_ESTIMATE

SCALE = 240
WINDOW_NS = 600 * 10**9
DEADLINE = 60.0


class PlcThread:
    """A :class:`PlcServer` serving a simulated day from its own event loop thread."""

    def __init__(self, day) -> None:
        self.loop = asyncio.new_event_loop()
        feed = PlantFeed(day, loop=True)
        self.server = PlcServer(load_tagmap(), feed.next_values, port=0, period_s=10.0 / SCALE)
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def __enter__(self) -> PlcThread:
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self.server.start(), self.loop).result(10)
        return self

    def __exit__(self, *exc: object) -> None:
        asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


def _line(proc: subprocess.Popen, timeout: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    try:
        if not sel.select(timeout):
            raise AssertionError("the daemon did not report in time")
        return proc.stdout.readline()
    finally:
        sel.close()


def _checkpoint(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (FileNotFoundError, ValueError):
        return None


def _wait_ticks(path: Path, n: int, proc: subprocess.Popen) -> dict:
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        doc = _checkpoint(path)
        if doc and doc["service"]["stats"]["ticks"] >= n:
            return doc
        if proc.poll() is not None:
            raise AssertionError(f"daemon exited: {proc.stderr.read()[-2000:]}")
        time.sleep(0.05)
    raise AssertionError(f"no checkpoint with {n} ticks within {DEADLINE} s")


@pytest.fixture(scope="module")
def day():
    return simulate_day(load_plant_config(), 3.0, 21)


def test_sigkill_then_resume_from_the_checkpoint(day, tmp_path: Path, capsys) -> None:
    config = tmp_path / "plant.toml"
    config.write_text(default_config_path().read_text() + f"""
[service]
data_dir = "{tmp_path / 'rec'}"
checkpoint = "{tmp_path / 'state' / 'checkpoint.json'}"
lab_dir = "{tmp_path / 'lab'}"
zenoh_listen = ["tcp/127.0.0.1:0"]
time_scale = {SCALE}
clock_start = "{int(day.scans.index[0])}"
chunk_size = 2048
flush_interval_s = 0.2
log_format = "json"
""")
    ckpt = tmp_path / "state" / "checkpoint.json"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with PlcThread(day) as plc:
        cmd = [sys.executable, "-m", "softsensor.cli", "run", "--config", str(config),
               "--plc", f"127.0.0.1:{plc.server.port}"]

        def start() -> tuple[subprocess.Popen, str]:
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True, env=env)
            return proc, _line(proc, DEADLINE)

        first, hello = start()
        try:
            assert hello.startswith("softsensor run: unit=dryer1 estimator=ukf zenoh=tcp/127.0")
            assert "resumed=false" in hello
            # which files it runs on (issue 13): this config, no params, the packaged tag map
            assert f"config={config} params=none tagmap=" in hello, hello
            assert "tagmap_dryer1.toml outputs=none" in hello, hello
            killed = _wait_ticks(ckpt, 3, first)
        finally:
            first.send_signal(signal.SIGKILL)
            first.communicate(timeout=DEADLINE)  # reaped, its pipes closed
        assert first.returncode == -signal.SIGKILL
        killed = _checkpoint(ckpt)  # the last one written before the kill
        n_killed = killed["service"]["stats"]["ticks"]
        end_killed = killed["service"]["ticked_end_ns"]

        second, hello = start()
        try:
            assert "resumed=true" in hello
            _wait_ticks(ckpt, n_killed + 2, second)
        finally:
            second.send_signal(signal.SIGTERM)
            out, err = second.communicate(timeout=DEADLINE)
        assert second.returncode == 0, err[-2000:]
        assert "softsensor run: stopped" in out
        assert plc.server.write_requests == 0
    lines = [json.loads(x) for x in err.splitlines() if x.startswith("{")]
    assert any(x["event"] == "resumed" and x["ticks"] == n_killed for x in lines)
    # the tick lines speak plant units: % moisture (wet basis by default), the local clock
    ticks = [x for x in lines if x["event"] == "tick" and x.get("moisture_out") is not None]
    assert ticks and all(3.0 < x["moisture_out"] < 30.0 and x["unit"] == "% wb"
                         and 0.0 < x["moisture_out_2sd"] < 10.0 for x in ticks), ticks[:2]
    assert all(x["window_end"].endswith("+00:00") for x in ticks), ticks[0]
    assert lines[-1]["event"] == "stopped"

    # the first file was cut by the kill; the second was finished by SIGTERM
    names = sorted(p.name for p in (tmp_path / "rec").glob("dryer1-*.mcap"))
    assert names == ["dryer1-20260105-01.mcap", "dryer1-20260105.mcap"]
    cut, clean = tmp_path / "rec" / names[1], tmp_path / "rec" / names[0]
    with pytest.raises(IngestError, match="truncated"):
        read_day(cut)
    before = read_day(cut, allow_truncated=True)
    after = read_day(clean)
    assert before.truncated and len(before.scans) > 0
    ends_before = [t for t, _ in before.topic(TOPIC_ESTIMATE)]
    ends_after = [t for t, _ in after.topic(TOPIC_ESTIMATE)]
    assert ends_before and max(ends_before) <= end_killed
    assert ends_after[0] == end_killed + WINDOW_NS  # resumed with the next window
    assert all(b - a == WINDOW_NS for a, b in zip(ends_after, ends_after[1:], strict=False))
    final = _checkpoint(ckpt)["service"]
    assert final["stats"]["ticks"] == n_killed + len(ends_after)

    # the recording up to the kill replays when asked, and fails in one line otherwise
    capsys.readouterr()
    assert cli_main(["replay", str(cut), "--out", str(tmp_path / "r.mcap")]) == 2
    err_line = capsys.readouterr().err.strip()
    assert err_line.count("\n") == 0 and "truncated or corrupt MCAP file" in err_line
    assert not (tmp_path / "r.mcap").exists()
    assert cli_main(["replay", str(cut), "--allow-truncated", "--out",
                     str(tmp_path / "r.mcap")]) == 0
    replayed = read_day(tmp_path / "r.mcap")
    assert len(replayed.scans) == len(before.scans)
    assert len(replayed.topic(TOPIC_ESTIMATE)) >= len(ends_before)
