"""Fault injection (issue 25, item 4, and item 8's ``resumed``): a checkpoint from a clock
that was ahead, against a real daemon.

Before: three ticks at ``--clock-start`` a day ahead, then a restart on that checkpoint at
``--time-scale 1`` resumed with ``window_end_ns`` a day ahead and dropped every real scan as
late: no tick in 21 minutes. And a daemon whose checkpoint was rejected still said
``resumed=true``. Now a checkpoint further ahead of the clock than ``max_future_s`` is
refused like any other future time (moved aside, fresh start) and ``resumed`` says what
happened.
"""

from __future__ import annotations

import asyncio
import logging
import time
from pathlib import Path

from daemon_harness import running_daemon

DAY_NS = 86_400 * 10**9


def test_a_checkpoint_from_a_clock_a_day_ahead_does_not_silence_a_real_time_daemon(
        tmp_path: Path, caplog):
    caplog.set_level(logging.INFO)
    got: dict = {}

    async def main() -> None:
        ahead = time.time_ns() + DAY_NS
        async with running_daemon(tmp_path, ticks=3, clock_start=str(ahead)) as r:
            got["ahead_end"] = r.daemon.worker.service.ticked_end_ns
        assert got["ahead_end"] > time.time_ns() + DAY_NS // 2
        # the same checkpoint, now on the wall clock (time scale 1, no clock start)
        async with running_daemon(tmp_path, ticks=0, time_scale=1.0, clock_start=None,
                                  poll_period_s=0.5) as r:
            loop = asyncio.get_running_loop()
            service = r.daemon.worker.service
            deadline, first = loop.time() + 20, service.stats.scans  # (restored, if resumed)
            while service.stats.scans < first + 6:
                assert loop.time() < deadline and not r.task.done(), service.stats
                await asyncio.sleep(0.1)
            await asyncio.to_thread(r.daemon.worker.sync)
            got.update(resumed=r.daemon.info.resumed, late=service.late_scans,
                       ticked=service.ticked_end_ns)

    asyncio.run(asyncio.wait_for(main(), 240))
    assert got["late"] == 0  # the real scans go into windows again
    assert got["resumed"] is False
    assert got["ticked"] is None or got["ticked"] < time.time_ns() + 600 * 10**9
    assert len(list(tmp_path.glob("ckpt.json.bad-*"))) == 1
    text = "\n".join(r.getMessage() + str(getattr(r, "softsensor_fields", ""))
                     for r in caplog.records)
    assert "checkpoint from the future" in text
