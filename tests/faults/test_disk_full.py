"""Fault injection (issue 25, item 5): the data folder's disk fills up, against a real daemon
recording into a real (small, tmpfs) file system.

Before: every message on a full disk opened a new day file and failed on its header: 507
zero-byte ``dryer1-YYYYMMDD-NN.mcap`` in two minutes across a day change, each one "not an
MCAP file" to ``replay``, and a warning per message. Now recording pauses (one error line,
health says ``recording: disk full``), estimates go on, no empty file is left, and
recording resumes, what waited in memory first, once there is room again.

Needs root (or a user namespace) to mount a small tmpfs; skipped with the reason otherwise.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import subprocess
from pathlib import Path

import pytest
from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import open_session
from softsensor.recording.mcap_day import read_day
from softsensor.service.day_replay import parse_time
from softsensor.service.watchdog import query_health
from softsensor.signals import TOPIC_ESTIMATE

MIDNIGHT = parse_time("2026-01-05T00:00:00Z")
S = 10**9


@contextlib.contextmanager
def small_disk(path: Path, size: str = "1m"):
    path.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs for a full disk: {done.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def _fill(folder: Path) -> Path:
    """Take every free byte of ``folder``'s file system (a real ENOSPC for the recorder);
    refuses any file system but a small one (never the machine's disk)."""
    st = os.statvfs(folder)
    assert st.f_blocks * st.f_frsize <= 16 * 1024 * 1024, f"{folder} is not a small disk"
    filler = folder / "filler.bin"
    block = b"\0" * 4096
    with open(filler, "wb", buffering=0) as f:
        with contextlib.suppress(OSError):
            while True:
                f.write(block)
    return filler


def _health(endpoint: str) -> dict:
    with open_session(mode="client", connect=[endpoint]) as s:
        answer = query_health(s, "dryer1", 5.0)
    assert answer.doc is not None, answer.problem
    return answer.doc


def test_a_full_disk_pauses_recording_without_litter_and_it_resumes(tmp_path: Path, caplog):
    caplog.set_level(logging.INFO)
    got: dict = {}

    async def wait(cond, what: str, r, timeout: float = 40.0) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not cond():
            assert loop.time() < deadline and not r.task.done(), f"waiting for {what}"
            await asyncio.sleep(0.05)

    async def main() -> None:
        async with running_daemon(tmp_path, ticks=0, clock_start=str(MIDNIGHT - 1200 * S),
                                  record_reserve_bytes=64 * 1024) as r:
            rec, clock = r.daemon.recorder, r.daemon.clock
            filler = _fill(tmp_path / "rec")
            ticks = r.daemon.worker.service.stats.ticks
            # across the day change and its 600 s grace, still full
            await wait(lambda: clock.now_ns() > MIDNIGHT + 900 * S, "the day change", r)
            got["files_full"] = sorted(p.name for p in (tmp_path / "rec").glob("*.mcap"))
            got["health"] = await asyncio.to_thread(_health, r.endpoint)
            got["ticks_while_full"] = r.daemon.worker.service.stats.ticks - ticks
            filler.unlink()
            got["freed_ns"] = clock.now_ns()
            await wait(lambda: getattr(rec, "failure", None) is None, "recording to resume", r)
            ticks = r.daemon.worker.service.stats.ticks
            await wait(lambda: r.daemon.worker.service.stats.ticks >= ticks + 2,
                       "two more ticks", r)

    with small_disk(tmp_path / "rec"):
        asyncio.run(asyncio.wait_for(main(), 240))
        files = sorted((tmp_path / "rec").glob("*.mcap"))
        sizes = {p.name: p.stat().st_size for p in files}
        estimates = []
        for p in files:  # every file opens (the one cut by the full disk with allow_truncated)
            estimates += [t for t, _b in read_day(p, allow_truncated=True).topic(TOPIC_ESTIMATE)]
    assert len(got["files_full"]) <= 1, got["files_full"]  # no file per message
    assert all(sizes.values()), sizes  # no empty day file
    assert got["ticks_while_full"] >= 2  # estimates went on
    assert got["health"].get("recording") == "disk full", got["health"]
    assert "recording: disk full" in got["health"]["detail"]
    assert max(estimates) > got["freed_ns"]  # recording resumed
    ends = sorted(set(estimates))  # what waited in memory while the disk was full, and
    gaps = [(a, b) for a, b in zip(ends, ends[1:], strict=False) if b - a != 600 * S]
    assert not gaps, gaps  # the open chunk the full disk cut, were written after: no gap
    paused = [r for r in caplog.records if "recording paused" in r.getMessage()]
    assert len(paused) == 1, [r.getMessage() for r in paused]


def test_the_recorder_loses_nothing_a_full_disk_interrupts(tmp_path: Path):
    """The recorder alone on the small disk: messages in the open chunk when the disk fills,
    and those that come while it is full, are all in the files once there is room again."""
    from softsensor.recording.recorder import Recorder
    from softsensor.signals import TOPIC_SCAN

    now = [0.0]
    with small_disk(tmp_path / "rec"):
        rec = Recorder(tmp_path / "rec", "dryer1", flush_interval_s=3600.0,
                       clock=lambda: now[0], retry_s=5.0)
        t0 = MIDNIGHT - 100 * 10 * S
        times = [t0 + i * 10 * S for i in range(300)]  # across midnight
        for t in times[:100]:
            rec.write(TOPIC_SCAN, t, {"T_air_in": 480.0})
        rec.flush()
        for t in times[100:150]:  # in the open chunk when the disk fills
            rec.write(TOPIC_SCAN, t, {"T_air_in": 481.0})
        filler = _fill(tmp_path / "rec")
        for t in times[150:250]:
            rec.write(TOPIC_SCAN, t, {"T_air_in": 482.0})
            rec.flush()  # (a chunk must reach the disk to find it full)
        assert rec.failure == "disk full"
        filler.unlink()
        now[0] += 10.0
        for t in times[250:]:
            rec.write(TOPIC_SCAN, t, {"T_air_in": 483.0})
        assert rec.failure is None
        rec.close()
        got = []
        for p in sorted((tmp_path / "rec").glob("*.mcap")):
            assert p.stat().st_size > 0
            got += [t for t, _b in read_day(p, allow_truncated=True).topic(TOPIC_SCAN)]
    assert sorted(got) == times and rec.n_lost == 0
