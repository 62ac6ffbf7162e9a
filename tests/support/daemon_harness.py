"""A real daemon polling the simulated PLC, for the fault tests that need one running, and its
parts for the system tests that start their own: the simulated PLC serving a day, the
daemon's settings with every file in the test's folder, what the daemon publishes."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path

from softsensor.ingest.tagmap import TagMap, load_tagmap
from softsensor.plant.plc_feed import PlantFeed
from softsensor.plant.plc_server import PlcServer
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.service.daemon import Daemon
from softsensor.service.settings import ServiceSettings, service_settings

SCALE = 240.0


@dataclass
class Running:
    daemon: Daemon
    stop: asyncio.Event
    task: asyncio.Task
    endpoint: str  #: where the daemon's Zenoh session listens


@contextlib.asynccontextmanager
async def serving_plc(day, *, clock: bool = False,
                      plc_values: Callable[[dict], dict] | None = None,
                      poll_period_s: float | None = None
                      ) -> AsyncIterator[tuple[PlantFeed, TagMap]]:
    """The simulated PLC serving ``day`` in a loop, :data:`SCALE` times the plant's pace (with
    ``clock``, the plant's time of the values in its clock registers; ``plc_values`` may change
    what it serves at each scan, a broken sensor; ``poll_period_s``: the tag map's poll period
    in plant seconds, 10 s by default); yields the feed and the tag map pointed at the server;
    the server stops on exit."""
    feed = PlantFeed(day, loop=True)
    tm = load_tagmap()
    if poll_period_s is not None:
        tm = tm.with_settings(poll_period_s=poll_period_s)
    values = feed.next_values if plc_values is None else (
        lambda: plc_values(feed.next_values()))
    plc = PlcServer(tm, values, port=0, period_s=10.0 / SCALE,
                    clock=(lambda: feed.plant_time_ns) if clock else None)
    await plc.start()
    try:
        yield feed, tm.with_endpoint("127.0.0.1", plc.port)
    finally:
        await plc.stop()


def published(daemon: Daemon, kind: str) -> list:
    """The outputs of ``kind`` (``"estimate"``, ``"health"``) that ``daemon`` publishes from now
    on, in order (its output hook wrapped: call it before the daemon runs)."""
    seen: list = []
    hook = daemon._on_output

    def spy(out):
        hook(out)
        if out.kind == kind:
            seen.append(out)

    daemon._on_output = spy
    return seen


def daemon_settings(tmp_path: Path, start_ns: int, cfg=None, **changes) -> ServiceSettings:
    """``[service]`` of the built-in plant (or ``cfg``), all files in ``tmp_path``,
    accelerated 240x."""
    cfg = cfg or load_plant_config()
    table = {"data_dir": str(tmp_path / "rec"), "checkpoint": str(tmp_path / "ckpt.json"),
             "lab_dir": str(tmp_path / "lab"), "zenoh_listen": ["tcp/127.0.0.1:0"],
             "flush_interval_s": 0.2, "time_scale": SCALE, "clock_start": str(start_ns),
             **changes}
    return service_settings(cfg).with_overrides(**table)


@contextlib.asynccontextmanager
async def running_daemon(tmp_path: Path, *, ticks: int = 1,
                         plc_values: Callable[[dict], dict] | None = None,
                         resume: bool | str = True, poll_period_s: float | None = None,
                         config_extra: str = "", **changes) -> AsyncIterator[Running]:
    """A daemon on a looping simulated day, yielded once it has ticked ``ticks`` times (0:
    once it is up); stopped (and awaited, at most 30 s) on exit. ``plc_values`` may change
    what the PLC serves at each of its scans (a broken sensor); ``poll_period_s`` is the
    poller's period in plant seconds (the tag map's 10 s by default); ``config_extra``: TOML
    tables appended to the built-in plant config."""
    cfg = load_plant_config()
    if config_extra:
        path = tmp_path / "plant.toml"
        path.write_text(default_config_path().read_text() + "\n" + config_extra)
        cfg = load_plant_config(path)
    day = simulate_day(cfg, 3.0, 12)
    settings = daemon_settings(tmp_path, int(day.scans.index[0]), cfg, **changes)
    async with serving_plc(day, plc_values=plc_values, poll_period_s=poll_period_s) as (_, tm):
        daemon = Daemon(cfg, settings, tagmap=tm, resume=resume)
        stop, up = asyncio.Event(), []
        task = asyncio.create_task(daemon.run(stop, ready=up.append))
        loop = asyncio.get_running_loop()
        try:
            deadline = loop.time() + 60
            while not up or daemon.worker.service.stats.ticks < ticks:
                assert loop.time() < deadline and not task.done(), "the daemon did not tick"
                await asyncio.sleep(0.05)
            yield Running(daemon, stop, task, up[0].endpoints[0])
        finally:
            stop.set()
            await asyncio.wait_for(task, 30)
