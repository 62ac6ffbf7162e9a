"""Fault injection (issue 25, items 1 and 3): values no sensor gives, against a real daemon.

Before: two scans of ``T_air_in = 1e308`` from a bus peer in one window overflowed the
window's ``fsum`` on every later message (no estimate again, about 14 log lines a second),
and the checkpoint kept the open window, so a restart resumed into the same stall. Twenty
PLC scans of ``T_air_in`` at 690 K (inside the tag map's 300..700 K) were averaged into a
window and published as an ``ok`` estimate of 37.5 % moisture. Now every value is judged
before a window sums it (range and rate of change, :mod:`softsensor.windows.plausibility`)
and the estimates go on from the sane values.
"""

from __future__ import annotations

import asyncio
import logging
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import Publisher, open_session, wait_for_peers
from softsensor.recording.mcap_day import read_day
from softsensor.signals import TOPIC_ESTIMATE


def _put_scans(endpoint: str, bodies: list[dict], times_ns: list[int]) -> None:
    with open_session(port=None, connect=[endpoint]) as s:
        assert wait_for_peers(s, timeout=10)
        pub = Publisher(s, "dryer1")
        pub.declare(("scan",))
        time.sleep(0.3)  # the declaration reaches the daemon
        for body, t in zip(bodies, times_ns, strict=True):
            pub.put("scan", body, t)
        time.sleep(0.3)
        pub.close()


async def _more_ticks(r, n: int, timeout: float = 60.0) -> None:
    loop = asyncio.get_running_loop()
    stats = r.daemon.worker.service.stats
    t0, deadline = stats.ticks, loop.time() + timeout
    while stats.ticks < t0 + n:
        assert loop.time() < deadline and not r.task.done(), (
            f"ticks stopped at {stats.ticks} (errors: {r.daemon.worker.n_errors})")
        await asyncio.sleep(0.05)


def test_huge_values_from_a_peer_neither_stall_the_estimator_nor_poison_its_checkpoint(
        tmp_path: Path, caplog):
    caplog.set_level(logging.WARNING)
    huge = {"T_air_in": 1e308}

    async def main() -> None:
        async with running_daemon(tmp_path, ticks=2) as r:
            now = r.daemon.clock.now_ns()
            await asyncio.to_thread(_put_scans, r.endpoint, [huge, huge], [now, now + 10**9])
            await _more_ticks(r, 3)  # the window with them closes, and two more
            assert r.daemon.worker.n_errors == 0
            # again, and stop while their window is open: the last checkpoint holds them
            now = r.daemon.clock.now_ns()
            await asyncio.to_thread(_put_scans, r.endpoint, [huge, huge], [now, now + 10**9])
            await asyncio.to_thread(r.daemon.worker.sync)
        async with running_daemon(tmp_path, ticks=1) as r:
            assert r.daemon.info.resumed
            await _more_ticks(r, 3)
            assert r.daemon.worker.n_errors == 0

    asyncio.run(asyncio.wait_for(main(), 240))
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert "fsum" not in text and "overflow" not in text.lower()


class _BrokenThermocouple:
    """What the PLC serves: the plant's values, with ``T_air_in`` replaced by ``value`` for
    the next ``n`` PLC scans once :meth:`start` is called."""

    def __init__(self) -> None:
        self.value, self.n = 0.0, 0

    def start(self, value: float, n: int) -> None:
        self.value, self.n = value, n

    def __call__(self, values: dict) -> dict:
        if self.n > 0:
            self.n -= 1
            return {**values, "T_air_in": self.value}
        return values


def test_an_implausible_input_inside_the_tag_range_never_makes_an_ok_estimate(tmp_path: Path):
    tc = _BrokenThermocouple()
    got: dict = {}

    async def main() -> None:
        async with running_daemon(tmp_path, ticks=3, plc_values=tc) as r:
            got["t690"] = r.daemon.clock.now_ns()
            tc.start(690.0, 20)  # inside the tag map's 300..700 K, no dryer's hot air
            await _more_ticks(r, 3)
            got["t600"] = r.daemon.clock.now_ns()
            tc.start(600.0, 20)  # a spike of 120 K in one 10 s scan
            await _more_ticks(r, 5)
            got["refused"] = r.daemon.worker.service.stats

    asyncio.run(asyncio.wait_for(main(), 240))
    (path,) = sorted((tmp_path / "rec").glob("*.mcap"))
    est = read_day(path).topic(TOPIC_ESTIMATE)
    after = [(t, b) for t, b in est if t > got["t690"]]
    for _t, b in after:
        if b["status"] == "ok":
            assert 0.05 < b["moisture_out"] < 0.16, b  # the truth is about 0.10
    refused = sum((b.get("inputs_refused") or {}).get("T_air_in", 0) for _t, b in after)
    assert refused >= 30, refused  # both faults were seen and refused at the edge
    # the model was never dragged off: the last windows after the spike are ok and sane
    last = [b for t, b in after if t > got["t600"]][-3:]
    assert any(b["status"] == "ok" for b in last), [(b["status"], b["detail"]) for b in last]
