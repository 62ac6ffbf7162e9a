"""Fault injection (issue 25, item 6): logs that a peer or a broken disk could flood, against
a real daemon.

Before: 20,000 non-JSON scans made 37,912 log lines (one from the estimator's subscriber and
one from the recorder's per message), 300 puts with 60 kB keys 16 MB of log with every key
in full, and a checkpoint folder the daemon cannot write one ``checkpoint_failed`` line a
tick. Now every repeated line is rate-limited with a count of what it held back, and text
from outside (keys, names, ids) is cut to a bounded length.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import open_session, wait_for_peers

LONG = "k" * 60_000


def _flood(endpoint: str, now_ns: int) -> None:
    with open_session(port=None, connect=[endpoint]) as s:
        assert wait_for_peers(s, timeout=10)
        scan = s.declare_publisher("plant/dryer1/scan")
        lab = s.declare_publisher("plant/dryer1/lab")
        time.sleep(0.3)
        for _ in range(3000):
            scan.put(b"this is not JSON")
        for i in range(300):
            s.put(f"plant/dryer1/{LONG}{i}", b"{}")  # a 60 kB key chunk
        for i in range(200):
            scan.put(json.dumps({LONG: 1.0, "time_ns": now_ns + i}).encode())
            lab.put(json.dumps({"sample_time_ns": now_ns, "moisture_out": 0.1,
                                "sample_id": LONG + str(i), "time_ns": now_ns}).encode())
        time.sleep(1.0)


def test_floods_of_bad_messages_are_a_few_short_lines(tmp_path: Path, caplog):
    got: dict = {}

    async def run() -> None:
        # a peer's scans into the estimator (by default they are kept out while the PLC's
        # arrive, issue 40): the lines its checks log are what this test bounds
        async with running_daemon(tmp_path, ticks=1, plc_scans_first=False) as r:
            await asyncio.to_thread(r.daemon.worker.sync)
            caplog.clear()
            caplog.set_level(logging.INFO)
            await asyncio.to_thread(_flood, r.endpoint, r.daemon.clock.now_ns())
            await asyncio.to_thread(r.daemon.worker.sync)
            got["records"] = list(caplog.records)
            got["bad"] = r.daemon.worker.service.stats.bad_scans
            got["dropped"] = dict(r.daemon.worker.dropped)  # said when it fails

    asyncio.run(asyncio.wait_for(run(), 150))
    noisy = [r for r in got["records"] if r.levelno >= logging.WARNING]
    lines = [r.getMessage() for r in noisy]
    # the flood arrived: how many bad scans reach the decoder past the rate limit depends on
    # how fast the flood went (176 on a quiet machine, 61 to 93 with the suite's other worker
    # busy); at least 40, more than the 25 lines allowed, so an unthrottled log would fail
    assert got["bad"] >= 40, (got["bad"], got["dropped"])
    assert len(noisy) <= 25, (len(noisy), lines[:30])
    longest = max((len(r.getMessage()) + len(str(getattr(r, "softsensor_fields", "")))
                   for r in got["records"]), default=0)
    assert longest <= 1000, longest


def test_a_checkpoint_that_cannot_be_written_is_said_once_in_a_while(tmp_path: Path, caplog):
    caplog.set_level(logging.ERROR)
    (tmp_path / "not-a-folder").write_text("a file where the checkpoint folder should be\n")
    ckpt = tmp_path / "not-a-folder" / "checkpoint.json"

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=5, checkpoint=str(ckpt)) as r:
            assert r.daemon.worker.service.stats.ticks >= 5

    asyncio.run(asyncio.wait_for(run(), 150))
    failed = [r for r in caplog.records if r.getMessage() == "checkpoint_failed"]
    assert 1 <= len(failed) <= 2, len(failed)  # five ticks (and the last save) failed
