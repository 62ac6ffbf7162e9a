"""The simulated PLC (``softsensor/plant/plc_server.py``) read by an independent Modbus client:
the plant's clock in its ``[clock]`` registers, as ``mbpoll`` reads it (issue 30)."""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess

import pytest
from daemon_harness import serving_plc

from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config


@pytest.mark.mbpoll
@pytest.mark.skipif(shutil.which("mbpoll") is None,
                    reason="mbpoll is not installed (apt-get install mbpoll)")
def test_the_virtual_plc_serves_its_plant_clock_to_mbpoll():
    """The demo's two clocks: the virtual PLC serves the time of the values it serves (the
    plant's clock, which runs on from the day's first scan), and mbpoll reads it there, a
    scan apart (the daemon that starts its clock on it: ``tests/system/
    test_commissioning.py``)."""
    day = simulate_day(load_plant_config(), 2.0, 5)
    got: dict = {}

    async def main() -> None:
        async with serving_plc(day, clock=True) as (feed, tagmap):
            await asyncio.sleep(2.0)  # the plant runs on: 480 plant seconds
            r = await asyncio.to_thread(subprocess.run, [
                "mbpoll", "-m", "tcp", "-a", "1", "-0", "-r", "20", "-c", "1", "-t", "3:int",
                "-B", "-1", "-p", str(tagmap.modbus.port), "127.0.0.1"],
                capture_output=True, text=True, timeout=30)
            got["mbpoll"] = (r.stdout, feed.plant_time_ns)

    asyncio.run(asyncio.wait_for(main(), 60))
    text, plant_ns = got["mbpoll"]
    served = int(re.search(r"\[20\]:\s+(-?\d+)", text).group(1))
    assert abs(served * 10**9 - plant_ns) <= 60 * 10**9, text  # one read, a scan apart
    assert plant_ns - int(day.scans.index[0]) > 300 * 10**9  # the plant ran on before
