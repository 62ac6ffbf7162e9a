"""Fault injection (issue 14, item 2): an estimator thread that cannot be starved, and says so
when it is stuck.

Before: every bus message went into an unbounded queue in front of the estimator thread, a
flood of scans from any peer grew it without limit, a stuck thread left the daemon without
estimates or health while its status line looked normal, and stopping waited up to a minute
for the thread. Now each source has a rate limit and the queue a bound (beyond them messages
are dropped and counted), a watchdog publishes ``stalled`` health when no estimate came for
more than one window past its time, and a stop is honoured within seconds even then.
"""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

from daemon_harness import SCALE, running_daemon

from softsensor.bus.zenoh_bus import Publisher, open_session, subscribe
from softsensor.cli import main
from softsensor.service.bus_worker import _Call
from softsensor.service.daemon import SHUTDOWN_WAIT_S


def _flood(endpoint: str, now_ns: int, n: int) -> float:
    with open_session(port=None, connect=[endpoint]) as s:
        time.sleep(1.0)
        pub = Publisher(s, "dryer1")
        pub.declare(("scan",))
        time.sleep(0.3)
        t0 = time.perf_counter()
        for i in range(n):
            pub.put("scan", {"T_air_in": 480.0, "m_air": 82.0}, now_ns + i)
        took = time.perf_counter() - t0
        time.sleep(0.5)
        pub.close()
        return took


def test_a_scan_flood_is_rate_limited_and_estimation_goes_on(tmp_path: Path):
    got: dict = {}

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=2) as r:
            p = r.daemon.worker
            t0 = p.service.stats.ticks
            got["took"] = await asyncio.to_thread(_flood, r.endpoint, r.daemon.clock.now_ns(),
                                                  30_000)
            got["dropped"] = dict(p.dropped)
            deadline = asyncio.get_running_loop().time() + 30
            while p.service.stats.ticks < t0 + 4:
                assert asyncio.get_running_loop().time() < deadline, "ticks stopped"
                await asyncio.sleep(0.05)
            got["pending"] = p.pending

    asyncio.run(asyncio.wait_for(run(), 150))
    # the flood came far faster than 10 scans a plant second (2,400 a wall second at 240x)
    assert 30_000 / got["took"] > 3 * 10 * SCALE, got
    assert got["dropped"]["rate"] > 10_000, got
    assert got["pending"] < 1000, got


def test_a_stuck_estimator_is_reported_stalled_and_stop_is_still_prompt(tmp_path: Path):
    got: dict = {"health": []}
    release = threading.Event()

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=1) as r:
            p, w = r.daemon.worker, r.daemon.watchdog
            with open_session(port=None, connect=[r.endpoint]) as s, \
                    subscribe(s, lambda m: got["health"].append(m.body), kinds=("health",)):
                p._q.put(_Call(lambda: release.wait(120)))  # the thread is stuck from now
                deadline = asyncio.get_running_loop().time() + w.limit_s + 10
                while not w.stalled:
                    assert asyncio.get_running_loop().time() < deadline, "no stall seen"
                    await asyncio.sleep(0.1)
                await asyncio.sleep(0.5)  # the stalled health reaches the subscriber
                got["verb"] = await asyncio.to_thread(
                    main, ["health", "--connect", r.endpoint, "--timeout", "3"])
            t0 = time.monotonic()
            r.stop.set()
            await asyncio.wait_for(r.task, SHUTDOWN_WAIT_S + 10)
            got["stop_s"] = time.monotonic() - t0

    try:
        asyncio.run(asyncio.wait_for(run(), 150))
    finally:
        release.set()
    stalled = [h for h in got["health"] if h.get("stalled")]
    assert stalled and stalled[0]["status"] == "stale", got["health"][-3:]
    assert "stalled" in stalled[0]["detail"]
    assert got["verb"] == 1, got  # the container's health check fails
    assert got["stop_s"] < SHUTDOWN_WAIT_S + 5, got


def test_the_watchdog_waits_one_window_past_the_latest_tick_time():
    t = {"tick": 0.0}
    from softsensor.service.watchdog import Watchdog

    w = Watchdog(600.0, 70.0, lambda: t["tick"], lambda: 3)
    assert w.check(now=1269.0) is None and not w.stalled  # 2 windows + grace not yet over
    stall = w.check(now=1271.0)
    assert stall is not None and stall.pending == 3 and stall.late_s == 1271.0 and w.stalled
    assert stall.reason.status == "stale" and "stalled" in stall.reason.text
    assert w.check(now=1300.0) is None  # announced once per window while it lasts
    assert w.check(now=1872.0) is not None
    t["tick"] = 1900.0
    assert w.check(now=1901.0) is None and not w.stalled and w.n_stalls == 1
