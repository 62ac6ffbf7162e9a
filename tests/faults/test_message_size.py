"""Fault injection (issue 25, item 8): oversized bus messages are counted, against a real
daemon.

Before: Zenoh's own limit was the daemon's ``max_message_bytes``, so every larger message was
dropped on the link before the daemon's check and ``too_large`` stayed 0 whatever came. Now
Zenoh's limit is four times it: what lies between reaches the daemon, which drops and counts
it before decoding; larger ones Zenoh may drop on the link unseen (bounded memory per link;
in Zenoh 1.10 some far larger ones still arrive and are counted).
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

from daemon_harness import running_daemon

from softsensor.bus.zenoh_bus import Publisher, open_session, wait_for_peers


def _send(endpoint: str, now_ns: int, sizes: list[int]) -> None:
    with open_session(port=None, connect=[endpoint]) as s:
        assert wait_for_peers(s, timeout=10)
        pub = Publisher(s, "dryer1")
        pub.declare(("lab",))
        time.sleep(0.3)
        for n in sizes:
            pub.put("lab", {"sample_time_ns": now_ns - 60 * 10**9, "moisture_out": 0.1,
                            "sample_id": "big", "note": "x" * n}, now_ns)
        time.sleep(0.5)
        pub.close()


def test_an_oversized_message_is_dropped_and_counted(tmp_path: Path):
    got: dict = {}

    async def run() -> None:
        async with running_daemon(tmp_path, ticks=0) as r:
            p = r.daemon.worker
            await asyncio.to_thread(_send, r.endpoint, r.daemon.clock.now_ns(),
                                    [100_000, 200_000])
            await asyncio.to_thread(p.sync)
            got.update(dropped=dict(p.dropped), labs=p.n_labs_received,
                       health=r.daemon._health_answer()["dropped"])

    asyncio.run(asyncio.wait_for(run(), 120))
    assert got["dropped"]["too_large"] == 2, got  # each counted, neither decoded
    assert got["labs"] == 0 and got["health"]["too_large"] == 2
