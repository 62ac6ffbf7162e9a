"""Fault injection (issue 31 item 1): the recorder stored what the rate limiter dropped.

A peer publishing 60 kB scans (under ``max_message_bytes``) for 10 s: the limiter admitted
about 123 and dropped 1,171, but 1,294 were recorded, 35 MB in 10 s (about 300 GB a day from
one peer). Now the daemon records the inputs its limits admit and nothing else (what they drop
goes into health as counts), and each topic adds at most ``record_topic_bytes_per_day`` to a
day's files. Real daemon, real simulated PLC, a real Zenoh peer on loopback, the real MCAP
files read back.

Issue 40: the cap was per topic, so a flood spent it and no real PLC scan was recorded for the
rest of the day, and a flood's values were averaged into the windows. Now the PLC's own scans
are known to the daemon: recorded under a cap of their own, and other senders' scans are kept
out of the windows while the PLC's arrive. And out of the recording: a recorded day is what the
estimator took, so ``replay``, ``calibrate`` and ``diagnose`` never read the flood.
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

from daemon_harness import running_daemon
from mcap.reader import make_reader

from softsensor.bus.zenoh_bus import Publisher, open_session

CAP = 2_000_000  # bytes of one topic per day
PAD = "x" * 60_000  # a 60 kB scan, under max_message_bytes (64 kB)


def _flood(endpoint: str, now_ns: int, n: int) -> None:
    with open_session(port=None, connect=[endpoint]) as s:
        time.sleep(1.0)
        pub = Publisher(s, "dryer1")
        pub.declare(("scan",))
        time.sleep(0.3)
        for i in range(n):
            pub.put("scan", {"T_air_in": 480.0, "m_air": 82.0, "pad": PAD}, now_ns + i)
        time.sleep(0.5)
        pub.close()


def _recorded(folder: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for path in sorted(folder.glob("*.mcap")):
        with open(path, "rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages():
                out.setdefault(channel.topic, []).append(message.data)
    return out


def test_the_recording_keeps_to_the_input_limits_and_a_daily_cap(tmp_path: Path):
    got: dict = {}

    async def run() -> None:
        # 0.25 scans a plant second: 60 a wall second at 240x, so most of the flood is dropped;
        # every sender's scans taken (as without a PLC), so the peer's reach the recording
        async with running_daemon(tmp_path, ticks=1, max_scan_rate_hz=0.25,
                                  record_topic_bytes_per_day=CAP, plc_scans_first=False) as r:
            p, rec = r.daemon.worker, r.daemon.bus_recorder
            await asyncio.to_thread(_flood, r.endpoint, r.daemon.clock.now_ns(), 600)
            await asyncio.sleep(0.5)
            got["recording"] = r.daemon._recording()
            t0 = p.service.stats.ticks
            deadline = asyncio.get_running_loop().time() + 30
            while p.service.stats.ticks < t0 + 1:  # a health after the flood is recorded
                assert asyncio.get_running_loop().time() < deadline, "ticks stopped"
                await asyncio.sleep(0.05)
            got["p"], got["rec"] = p, rec
        # the daemon has stopped: its counters and its files are final
        got["received"] = got["p"].subscription.n_received
        got["dropped"] = dict(got["p"].dropped)
        got["capped"] = dict(got["rec"].capped)

    asyncio.run(asyncio.wait_for(run(), 150))
    day = _recorded(tmp_path / "rec")
    scans = day["/plant/scan"]
    admitted = got["received"] - got["dropped"]["rate"] - got["dropped"]["queue_full"] \
        - got["dropped"]["other_sender"]
    assert got["dropped"]["rate"] > 300, got  # the limiter dropped most of the flood
    # what the limits dropped is not recorded; of what they admitted, the cap's share
    assert len(scans) + got["capped"]["/plant/scan"] == admitted, (len(scans), got)
    # the flood's bytes within the cap (the PLC's own scans have a cap of their own)
    flood = [b for b in scans if b"pad" in b]
    assert sum(len(b) for b in flood) <= CAP
    assert sum(len(b) for b in flood) > CAP - 70_000  # (the cap, not something else)
    assert "record_topic_bytes_per_day" in got["recording"] and "/plant/scan" in got["recording"]
    health = [json.loads(b) for b in day["/softsensor/health"]]
    assert max(h.get("inputs_dropped", {}).get("rate", 0) for h in health) > 300  # as counts
    assert max(h.get("recording_capped", {}).get("/plant/scan", 0) for h in health) > 0
    assert day["/softsensor/estimate"]  # the rest goes on being recorded


def test_a_flood_while_the_plc_serves_is_neither_recorded_nor_estimated(tmp_path: Path):
    got: dict = {}

    async def run() -> None:
        # a high rate: the limiter admits the flood (as the probe's at 60x); the PLC's scans
        # arriving, the daemon refuses it
        async with running_daemon(tmp_path, ticks=1, max_scan_rate_hz=50.0,
                                  record_topic_bytes_per_day=CAP) as r:
            d = r.daemon
            stats, poller = d.worker.service.stats, d.poller
            scans0, polls0 = stats.scans, poller.stats.scans
            got["flood_ns"] = d.clock.now_ns()
            await asyncio.to_thread(_flood, r.endpoint, d.clock.now_ns(), 600)
            t0 = stats.ticks
            deadline = asyncio.get_running_loop().time() + 30
            while stats.ticks < t0 + 2:  # real scans after the flood, windows ticked
                assert asyncio.get_running_loop().time() < deadline, "ticks stopped"
                await asyncio.sleep(0.05)
            got["estimated"] = stats.scans - scans0
            got["polled"] = poller.stats.scans - polls0
            got["other"] = d.worker.dropped["other_sender"]
            got["capped"] = dict(d.bus_recorder.capped)

    asyncio.run(asyncio.wait_for(run(), 150))
    scans = []  # (log time, is the flood's)
    for path in sorted((tmp_path / "rec").glob("*.mcap")):
        with open(path, "rb") as f:
            for _schema, _channel, m in make_reader(f).iter_messages(topics=["/plant/scan"]):
                scans.append((m.log_time, b"pad" in m.data))
    assert got["other"] > 300, got  # the flood was refused: none of it reached the windows
    # every scan the estimator took is one the PLC served (none of the flood's)
    assert 0 < got["estimated"] <= got["polled"] + 1, got
    # none of it was recorded either (a replay of the day reads what the estimator took) ...
    assert not any(flood for _t, flood in scans), sum(flood for _t, flood in scans)
    assert got["capped"].get("/plant/scan", 0) == 0, got  # (so it spent no cap)
    # ... and the PLC's own scans were, through the flood and after it
    assert sum(1 for t, flood in scans if not flood and t > got["flood_ns"]) >= 5, scans[-20:]
