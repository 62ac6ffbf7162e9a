"""The recorder: daily rotation, flushing, the bus adapter, and crash safety in a subprocess."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import threading
import time
from datetime import date
from pathlib import Path

import pytest

from softsensor.bus.zenoh_bus import (
    Publisher,
    free_port,
    listening_endpoints,
    open_session,
    wait_for_peers,
)
from softsensor.errors import IngestError
from softsensor.recording.mcap_day import read_day
from softsensor.recording.recorder import Recorder, day_file_name, utc_date
from softsensor.service.bus_recorder import BusRecorder
from softsensor.signals import SCAN_SIGNALS, TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN

MIDNIGHT = 1_750_032_000 * 10**9  # 2025-06-16T00:00:00Z
PERIOD = 10 * 10**9
DEADLINE = 10.0  # [s]


def _scan(i: int) -> dict:
    return {name: 300.0 + k + i for k, name in enumerate(SCAN_SIGNALS)}


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_names() -> None:
    assert utc_date(MIDNIGHT) == date(2025, 6, 16)
    assert utc_date(MIDNIGHT - 1) == date(2025, 6, 15)
    assert day_file_name("dryer1", date(2025, 6, 16)) == "dryer1-20250616.mcap"
    assert day_file_name("dryer1", date(2025, 6, 16), 2) == "dryer1-20250616-02.mcap"


def test_daily_rotation(tmp_path: Path) -> None:
    with Recorder(tmp_path, "dryer1", grace_s=600.0) as rec:
        for i in range(-30, 30):  # 5 min either side of midnight
            rec.write(TOPIC_SCAN, MIDNIGHT + i * PERIOD, _scan(i))
        # late messages within the grace period still go to their own day
        rec.write(TOPIC_ESTIMATE, MIDNIGHT, {"moisture_out": 0.1})
        rec.write(TOPIC_HEALTH, MIDNIGHT - 5 * 10**9, {"status": "ok", "detail": "late"})
        assert len(rec.open_paths) == 2
        rec.write(TOPIC_HEALTH, MIDNIGHT + 601 * 10**9, {"status": "ok", "detail": "next"})
        assert len(rec.open_paths) == 1  # past the grace: the old day is finished
        rec.write(TOPIC_HEALTH, MIDNIGHT - 2 * 10**9, {"status": "ok", "detail": "straggler"})
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["dryer1-20250615.mcap", "dryer1-20250616.mcap"]
    old = read_day(tmp_path / "dryer1-20250615.mcap")
    new = read_day(tmp_path / "dryer1-20250616.mcap")
    assert not old.truncated and not new.truncated
    assert len(old.scans) == 30 and old.scans.index.max() < MIDNIGHT
    assert len(new.scans) == 30 and new.scans.index.min() == MIDNIGHT
    assert old.topic(TOPIC_HEALTH)[0][1]["detail"] == "late"
    # the straggler after the grace period lands in the newest file, in log-time order
    assert [b["detail"] for _, b in new.topic(TOPIC_HEALTH)] == ["straggler", "next"]
    assert new.topic(TOPIC_ESTIMATE) == [(MIDNIGHT, {"moisture_out": 0.1})]


def test_restart_never_overwrites(tmp_path: Path) -> None:
    for k in range(3):
        with Recorder(tmp_path) as rec:
            rec.write(TOPIC_SCAN, MIDNIGHT + k, _scan(k))
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["dryer1-20250616-01.mcap", "dryer1-20250616-02.mcap", "dryer1-20250616.mcap"]


def test_flush_interval(tmp_path: Path) -> None:
    clock = FakeClock()
    rec = Recorder(tmp_path, chunk_size=1 << 20, flush_interval_s=5.0, clock=clock)
    try:
        for i in range(10):
            rec.write(TOPIC_SCAN, MIDNIGHT + i * PERIOD, _scan(i))
        (path,) = rec.open_paths
        assert len(read_day(path, allow_truncated=True).scans) == 0  # all in the open chunk
        clock.t = 6.0
        rec.tick()
        day = read_day(path, allow_truncated=True)
        assert day.truncated and len(day.scans) == 10
        rec.write(TOPIC_SCAN, MIDNIGHT + 10 * PERIOD, _scan(10))
        rec.flush()
        assert len(read_day(path, allow_truncated=True).scans) == 11
        with pytest.raises(IngestError, match="truncated"):
            read_day(path)
    finally:
        rec.close()
    assert len(read_day(path).scans) == 11
    with pytest.raises(ValueError, match="closed"):
        rec.write(TOPIC_SCAN, MIDNIGHT, {})


def test_thread_safety(tmp_path: Path) -> None:
    with Recorder(tmp_path, chunk_size=1024) as rec:
        def worker(k: int) -> None:
            for i in range(500):
                rec.write(TOPIC_SCAN, MIDNIGHT + (k * 500 + i) * 10**6, _scan(i))

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(4)]
        for th in threads:
            th.start()
        for th in threads:
            th.join(DEADLINE)
        (path,) = rec.open_paths
    assert len(read_day(path).scans) == 2000


def test_bus_recorder(tmp_path: Path) -> None:
    with open_session(port=0) as a, Recorder(tmp_path, "u3") as rec:
        (endpoint,) = listening_endpoints(a)
        with open_session(port=None, connect=[endpoint]) as b:
            assert wait_for_peers(b, timeout=DEADLINE)
            with BusRecorder(a, rec, unit="u3") as bus, Publisher(b, unit="u3") as pub:
                assert pub.wait_matched(timeout=DEADLINE)
                for i in range(20):
                    pub.put("scan", _scan(i), time_ns=MIDNIGHT + i * PERIOD)
                pub.put("lab", {"sample_time_ns": MIDNIGHT, "moisture_out": 0.11,
                                "sample_id": "L1"}, time_ns=MIDNIGHT + 5)
                pub.put("estimate", {"moisture_out": 0.1, "lab_updated": True},
                        time_ns=MIDNIGHT + 6)
                pub.put("health", {"status": "ok", "detail": "x"}, time_ns=MIDNIGHT + 7)
                deadline = time.monotonic() + DEADLINE
                while bus.n_received < 23 and time.monotonic() < deadline:
                    time.sleep(0.01)
        (path,) = rec.paths
    day = read_day(path)
    assert path.name == "u3-20250616.mcap"
    assert len(day.scans) == 20 and day.scans["T_air_in"].iloc[3] == 303.0
    assert day.labs["sample_id"].tolist() == ["L1"]
    assert day.topic(TOPIC_ESTIMATE) == [(MIDNIGHT + 6, {"moisture_out": 0.1,
                                                         "lab_updated": True})]
    assert day.topic(TOPIC_HEALTH)[0][1] == {"status": "ok", "detail": "x"}
    assert "time_ns" not in day.topic(TOPIC_SCAN)[0][1]
    assert set(day.topics) == {TOPIC_SCAN, TOPIC_LAB, TOPIC_ESTIMATE, TOPIC_HEALTH}


# --- crash safety: a recorder daemon in a subprocess ----------------------------------------


def _read_line(proc: subprocess.Popen, timeout: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    try:
        if not sel.select(timeout):
            raise AssertionError("recorder subprocess did not answer in time")
        return proc.stdout.readline()
    finally:
        sel.close()


def _start_recorder(tmp_path: Path, port: int, flush_interval: float) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "softsensor.service.bus_recorder", "--dir", str(tmp_path),
         "--unit", "dryer1", "--port", str(port), "--chunk-size", "2048",
         "--flush-interval", str(flush_interval)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert _read_line(proc, DEADLINE).strip() == "recording"
    except BaseException:
        proc.kill()
        proc.communicate(timeout=DEADLINE)  # reaped, its pipes closed
        raise
    return proc


def _publish_to(port: int, n: int) -> None:
    with open_session(port=None, connect=[f"tcp/127.0.0.1:{port}"]) as s:
        assert wait_for_peers(s, timeout=DEADLINE)
        with Publisher(s) as pub:
            assert pub.wait_matched(timeout=DEADLINE)
            for i in range(n):
                pub.put("scan", _scan(i), time_ns=MIDNIGHT + i * PERIOD)
            time.sleep(0.3)  # let the last puts cross the wire before closing


@pytest.mark.parametrize("flush_interval, max_lost", [(0.2, 0), (1000.0, 12)])
def test_sigkill_loses_at_most_the_open_chunk(tmp_path: Path, flush_interval: float,
                                              max_lost: int) -> None:
    port = free_port()
    proc = _start_recorder(tmp_path, port, flush_interval)
    try:
        _publish_to(port, 500)
        time.sleep(1.5)  # > flush interval + ticker period
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=DEADLINE)  # reaped, its pipes closed
    assert proc.returncode == -signal.SIGKILL
    (path,) = tmp_path.glob("dryer1-*.mcap")
    with pytest.raises(IngestError, match="truncated"):
        read_day(path)
    day = read_day(path, allow_truncated=True)
    assert day.truncated
    n = len(day.scans)
    assert 500 - max_lost <= n <= 500
    # what was kept is exactly the first n scans
    assert day.scans.index.tolist() == [MIDNIGHT + i * PERIOD for i in range(n)]
    assert day.scans["T_air_in"].tolist() == [300.0 + i for i in range(n)]


def test_sigterm_closes_files_cleanly(tmp_path: Path) -> None:
    port = free_port()
    proc = _start_recorder(tmp_path, port, 1000.0)
    try:
        _publish_to(port, 300)
        time.sleep(0.3)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=DEADLINE)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(DEADLINE)
    assert proc.returncode == 0, err
    assert "recorded 300 messages" in out
    (path,) = tmp_path.glob("dryer1-*.mcap")
    day = read_day(path)  # no allow_truncated needed
    assert not day.truncated and len(day.scans) == 300


def test_the_day_file_is_the_recorder_clocks_day_when_it_has_one(tmp_path):
    """Live, a message's own time (a peer's clock, minutes ahead at midnight) never names a
    day file: the recorder clock's day does."""
    from softsensor.recording.recorder import Recorder

    day_ns = 1_767_225_600 * 10**9  # 2026-01-01T00:00Z
    rec = Recorder(tmp_path, unit="dryer1")
    rec.write("/plant/scan", day_ns - 60 * 10**9 + 4 * 60 * 10**9, {"T_air_in": 480.0},
              file_time_ns=day_ns - 60 * 10**9)  # stamped 3 min into the new day
    rec.close()
    assert [p.name for p in rec.paths] == ["dryer1-20251231.mcap"]
