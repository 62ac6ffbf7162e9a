"""``softsensor simulate`` (a virtual plant's day as MCAP) and ``softsensor plant-server`` (a
virtual plant as a Modbus TCP PLC, for tests and demos).

Both choose the plant the same way: ``--plant independent`` (default;
:mod:`softsensor.plant.independent`, a dryer simulated apart from the model, member
``--plant-seed``) or ``--plant model`` (:mod:`softsensor.plant.simulator`, the model itself
with known parameters, ``--params``).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time
from pathlib import Path

from softsensor.apps.loading import load_config_and_params
from softsensor.errors import ConfigError
from softsensor.files import writing
from softsensor.plant.day import SimulatedDay
from softsensor.plant.effects import EFFECTS
from softsensor.plantconfig import PlantConfig

log = logging.getLogger(__name__)

PLANTS = ("independent", "model")


def add_plant_options(p: argparse.ArgumentParser) -> None:
    """``--plant``, ``--plant-seed`` and ``--params`` of the verbs that run a virtual plant."""
    p.add_argument("--plant", choices=PLANTS, default="independent",
                   help="independent: a dryer simulated apart from the model (default); "
                        "model: the model itself with known parameters")
    p.add_argument("--plant-seed", type=int, default=0, metavar="P",
                   help="which member of the independent plant family (default 0)")
    p.add_argument("--params", default=None,
                   help="true parameters of --plant model (PARAMS.toml)")


def load_plant(args: argparse.Namespace) -> PlantConfig:
    """The plant config of ``args``, with ``--params`` applied (``--plant model`` only)."""
    if args.params and args.plant != "model":
        raise ConfigError("--params applies to --plant model only (the independent plant "
                          "has no model parameters)")
    return load_config_and_params(args).config


def simulate_plant(cfg: PlantConfig, args: argparse.Namespace) -> SimulatedDay:
    """Run the plant chosen by ``args`` for ``args.hours``."""
    if args.plant == "model":
        from softsensor.plant.simulator import simulate_day

        return simulate_day(cfg, args.hours, args.seed, args.effect, args.magnitude)
    from softsensor.plant.independent import simulate_independent_day

    return simulate_independent_day(cfg, args.hours, args.seed, args.effect, args.magnitude,
                                    plant_seed=args.plant_seed)


#: Wall seconds between the lines saying the plant is still being simulated.
HEARTBEAT_S = 10.0


async def _simulated(cfg: PlantConfig, args: argparse.Namespace, plant: str) -> SimulatedDay:
    """The day to serve, simulated on a worker thread while a line every
    :data:`HEARTBEAT_S` says so (it takes tens of seconds: commissioning the plant, compiling
    its kernels, then the day; silence looked like a hang)."""
    say = (lambda _text: None) if args.quiet else (
        lambda text: print(f"plant-server: {text}", file=sys.stderr, flush=True))
    say(f"simulating {args.hours:g} h of {plant}, seed {args.seed}"
        f"{'' if args.effect is None else f', effect {args.effect}'}; serving starts when "
        "it is done")
    work = asyncio.ensure_future(asyncio.to_thread(simulate_plant, cfg, args))
    t0 = time.monotonic()
    while True:
        done, _ = await asyncio.wait({work}, timeout=HEARTBEAT_S)
        if done:
            return work.result()
        say(f"still simulating ({time.monotonic() - t0:.0f} s so far)")


async def _serve(args: argparse.Namespace) -> int:
    from softsensor.ingest.tagmap import load_tagmap
    from softsensor.plant.plc_feed import PlantFeed
    from softsensor.plant.plc_server import PlcServer, check_port
    from softsensor.plant.settings import virtual_plant_settings

    cfg = load_plant(args)
    tagmap = load_tagmap(args.tagmap) if args.tagmap else load_tagmap()
    if args.speed <= 0:
        raise ConfigError(f"--speed must be > 0, got {args.speed}")
    if args.lab_dir is not None and Path(args.lab_dir).exists() \
            and not Path(args.lab_dir).is_dir():
        raise ConfigError(f"--lab-dir {args.lab_dir}: exists and is not a folder")
    check_port(args.host, args.port)
    plant = (f"plant independent (plant seed {args.plant_seed})"
             if args.plant == "independent" else "plant model")
    t0 = time.monotonic()
    day = await _simulated(cfg, args, plant)
    if not args.quiet:
        print(f"plant-server: simulated {len(day.scans)} scans and {len(day.labs)} lab results "
              f"in {time.monotonic() - t0:.1f} s", file=sys.stderr, flush=True)
    feed = PlantFeed(day, lab_dir=args.lab_dir, loop=not args.once)
    period = virtual_plant_settings(cfg).scan_period / args.speed
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    server = PlcServer(tagmap, feed.next_values, host=args.host, port=args.port,
                       period_s=period, clock=lambda: feed.plant_time_ns)
    await server.start()
    print(f"plant-server: serving {tagmap.source} on {args.host}:{server.port}, "
          f"one scan every {period:g} s ({args.speed:g}x real time), {plant}", flush=True)
    try:
        while not stop.is_set() and not feed.finished:
            try:
                await asyncio.wait_for(stop.wait(), timeout=0.5)
            except TimeoutError:
                pass
    finally:
        await server.stop()
    log.info("plant-server stopped: %d requests, %d write requests refused",
             server.requests, server.write_requests)
    return 0


def _plant_server(args: argparse.Namespace) -> int:
    return asyncio.run(_serve(args))


def _simulate(args: argparse.Namespace) -> int:
    cfg = load_plant(args)
    day = simulate_plant(cfg, args)
    with writing(args.out) as tmp:  # a run stopped half-way leaves no half file
        day.write(tmp)
    eff = day.effect
    what = "clean day" if eff["effect"] == "none" else (
        f"effect {eff['effect']} magnitude {eff['magnitude']:g} {eff['unit']}"
        + (f" on {eff['channel']}" if eff.get("channel") else ""))
    plant = ("plant independent, plant seed " + str(args.plant_seed)
             if args.plant == "independent" else "plant model")
    print(f"wrote {args.out}: {len(day.scans)} scans over {args.hours:g} h, "
          f"{len(day.labs)} lab results, {what}, seed {args.seed}, {plant}", file=sys.stderr)
    return 0


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run a virtual plant and record a day as MCAP")
    p.add_argument("--hours", type=float, default=48.0, help="length of the record [h]")
    p.add_argument("--seed", type=int, default=0, help="seed of every random stream of the day")
    p.add_argument("--effect", default=None, metavar="CAUSE",
                   help=f"hide one effect in the day: {', '.join(EFFECTS)}")
    p.add_argument("--magnitude", type=float, default=None,
                   help="size of the effect (units and ranges: softsensor.plant.effects)")
    add_plant_options(p)
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--out", required=True, metavar="DAY.mcap", help="MCAP file to write")
    p.set_defaults(func=_simulate)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``simulate`` and ``plant-server`` on the ``softsensor`` parser."""
    _add_simulate(sub)
    p = sub.add_parser("plant-server", help="serve a virtual plant over Modbus TCP")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    p.add_argument("--port", type=int, default=5020, help="TCP port (0: any free port)")
    p.add_argument("--tagmap", default=None, help="tag map TOML (default config/tagmap)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    add_plant_options(p)
    p.add_argument("--hours", type=float, default=48.0, help="length of the simulated day")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of every random stream of the served day (default 0)")
    p.add_argument("--effect", default=None, metavar="CAUSE",
                   help=f"hide one effect in the day: {', '.join(EFFECTS)}")
    p.add_argument("--magnitude", type=float, default=None,
                   help="size of the effect (units and ranges: softsensor.plant.effects)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="time acceleration: 1 = real time, 60 = one plant minute per second")
    p.add_argument("--lab-dir", default=None,
                   help="drop lab results as JSON files into this folder when they are due")
    p.add_argument("--once", action="store_true", help="stop at the end of the day")
    p.add_argument("--quiet", action="store_true",
                   help="no progress lines on stderr (the serving line on stdout stays)")
    p.set_defaults(func=_plant_server)
