"""Fault injection (issue 14, item 1): scans stamped far from the daemon's clock, from another
peer on the bus, against a real daemon polling the simulated PLC.

Before the time gate, one scan two days ahead made the daemon tick 288 stale windows at once
and then drop every real scan as late (no estimate for two plant days), and one stamped
``time_ns = -5`` broke the recorder's open chunk. Now both are refused and counted, the
daemon keeps estimating from the real scans, and the recorded day has neither and reads back
whole.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import Publisher, open_session, wait_for_peers
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.service.settings import service_settings
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_SCAN

DAY_NS = 86_400 * 10**9


def _inject(endpoint: str, now_ns: int) -> None:
    with open_session(port=None, connect=[endpoint]) as s:
        assert wait_for_peers(s, timeout=10)
        pub = Publisher(s, "dryer1")
        pub.declare(("scan", "lab"))
        time.sleep(0.3)  # the declarations reach the daemon
        scan = {"T_air_in": 480.0, "m_air": 82.0}
        pub.put("scan", scan, now_ns + 2 * DAY_NS)
        pub.put("scan", scan, -5)
        pub.put("lab", {"sample_time_ns": now_ns + 2 * DAY_NS - 60 * 10**9,
                        "moisture_out": 0.1, "sample_id": "future"}, now_ns + 2 * DAY_NS)
        time.sleep(0.5)
        pub.close()


def test_far_future_and_negative_scans_are_refused_and_estimation_goes_on(tmp_path: Path):
    got: dict = {}

    async def main() -> None:
        # a peer's scans into the estimator (by default they are kept out while the PLC's
        # arrive, issue 40): its time gate is what this test checks
        async with running_daemon(tmp_path, ticks=2, plc_scans_first=False) as r:
            loop = asyncio.get_running_loop()
            stats = r.daemon.worker.service.stats
            got["start"] = r.daemon.clock.start_ns
            await asyncio.to_thread(_inject, r.endpoint, r.daemon.clock.now_ns())
            t0, deadline = stats.ticks, loop.time() + 60
            while stats.ticks < t0 + 4:  # four more windows (10 s wall at 240x)
                assert loop.time() < deadline and not r.task.done(), "ticks stopped"
                await asyncio.sleep(0.05)
            got["stats"] = stats

    asyncio.run(asyncio.wait_for(main(), 150))
    stats = got["stats"]
    assert stats.refused_time == 3, stats  # two scans and the lab
    assert stats.labs_refused == 0 and stats.labs_accepted == 0
    # estimation went on from the real scans: no burst of stale windows
    assert stats.stale_ticks <= 1 and stats.ticks >= 6, stats
    files = sorted((tmp_path / "rec").glob("*.mcap"))
    assert len(files) == 1, files  # no file for the day two days ahead
    rec = read_day(files[0])  # whole: footer written, nothing negative in it
    times = [t for t, _b in rec.topic(TOPIC_SCAN)]
    assert min(times) > 0 and max(times) < got["start"] + DAY_NS
    assert len(rec.topic(TOPIC_ESTIMATE)) >= 6


def test_a_lab_flood_is_bounded_and_does_not_starve_the_estimator():
    """40,000 lab messages used to take minutes of the estimator thread (every one sorted in
    and then applied by the filter): now at most ``max_pending_labs`` wait for a tick, the rest
    are refused and counted, and the tick after the flood takes no longer than a few updates."""
    from softsensor.service.build import make_service

    cfg = load_plant_config()
    service = make_service(cfg, service_settings(cfg))
    day = simulate_day(cfg, 0.5, 3)
    t0 = int(day.scans.index[0])
    rows = day.scans.to_dict("records")
    for k in range(61):
        service.on_scan(t0 + k * 10 * 10**9, rows[k])
    start = time.perf_counter()
    for i in range(40_000):
        service.on_lab({"sample_time_ns": t0 + 300 * 10**9, "moisture_out": 0.1,
                        "sample_id": f"flood-{i}"}, t0 + 600 * 10**9)
    taking = time.perf_counter() - start
    assert len(service._labs) == service.max_pending_labs == 50
    assert service.stats.labs_refused == 40_000 - 50
    assert taking < 10.0, taking  # 40,000 refusals, not 40,000 sorts
    t1 = time.perf_counter()
    for k in range(61, 130):
        service.on_scan(t0 + k * 10 * 10**9, rows[k])
    assert service.stats.ticks >= 1 and time.perf_counter() - t1 < 60.0


def test_a_scan_thirty_days_ahead_costs_a_bounded_number_of_ticks():
    """Where no clock refuses it (a replay, or a gate opened wide), one scan stamped 30 days
    ahead used to tick 4,320 stale windows in one burst; now the gap is one "stale since"
    state: at most the past horizon's windows are ticked, the rest counted and named."""
    from softsensor.service.build import make_service

    cfg = load_plant_config()
    settings = service_settings(cfg)
    service = make_service(cfg, settings)
    day = simulate_day(cfg, 0.5, 5)
    t0 = int(day.scans.index[0])
    rows = day.scans.to_dict("records")
    for k in range(70):
        service.on_scan(t0 + k * 10 * 10**9, rows[k])
    before = service.stats.ticks
    start = time.perf_counter()
    out = service.on_scan(t0 + 30 * DAY_NS, rows[70])
    out += service.advance(t0 + 30 * DAY_NS + 3600 * 10**9)
    ticks = service.stats.ticks - before
    horizon = int(settings.max_past_s // 600)
    assert 1 <= ticks <= horizon + 8, ticks
    assert service.stats.skipped_windows > 4000, service.stats.skipped_windows
    health = [o.to_body() for o in out if o.kind == "health"][-1]
    assert health["stale_since_ns"] is not None and health["status"] == "stale"
    assert health["stale_since_ns"] < t0 + DAY_NS
    assert time.perf_counter() - start < 60.0


def test_skipped_windows_keep_counting_across_a_restore():
    """A restored service counts a new long gap on top of the checkpoint's count (its
    accumulator is new and starts from zero)."""
    from softsensor.service.build import make_service

    cfg = load_plant_config()
    settings = service_settings(cfg)
    service = make_service(cfg, settings)
    rows = simulate_day(cfg, 0.5, 5).scans.to_dict("records")
    t0 = 1_767_571_200 * 10**9
    service.on_scan(t0, rows[0])
    service.on_scan(t0 + 10 * DAY_NS, rows[1])
    first = service.stats.skipped_windows
    assert first > 1000
    again = make_service(cfg, settings)
    again.restore(service.checkpoint())
    again.on_scan(t0 + 20 * DAY_NS, rows[2])
    assert again.stats.skipped_windows > first + 1000, (first, again.stats.skipped_windows)
