"""``softsensor plant-server``: the virtual plant as a Modbus TCP PLC (tests and demos)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal

from softsensor.plant.effects import EFFECTS

log = logging.getLogger(__name__)


async def _serve(args: argparse.Namespace) -> int:
    from softsensor.ingest.tagmap import load_tagmap
    from softsensor.plant.plc_feed import PlantFeed
    from softsensor.plant.plc_server import PlcServer
    from softsensor.plant.settings import virtual_plant_settings
    from softsensor.plant.simulator import simulate_day
    from softsensor.plantconfig import load_parameters, load_plant_config

    cfg = load_plant_config(args.config)
    if args.params:
        cfg = load_parameters(args.params, cfg)
    tagmap = load_tagmap(args.tagmap) if args.tagmap else load_tagmap()
    if args.speed <= 0:
        raise SystemExit("softsensor: --speed must be > 0")
    day = simulate_day(cfg, args.hours, args.seed, args.effect, args.magnitude)
    feed = PlantFeed(day, lab_dir=args.lab_dir, loop=not args.once)
    period = virtual_plant_settings(cfg).scan_period / args.speed
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    server = PlcServer(tagmap, feed.next_values, host=args.host, port=args.port,
                       period_s=period)
    await server.start()
    print(f"plant-server: serving {tagmap.source} on {args.host}:{server.port}, "
          f"one scan every {period:g} s ({args.speed:g}x real time)", flush=True)
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


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plant-server", help="serve the virtual plant over Modbus TCP")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default loopback)")
    p.add_argument("--port", type=int, default=5020, help="TCP port (0: any free port)")
    p.add_argument("--tagmap", default=None, help="tag map TOML (default config/tagmap)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--params", default=None, help="true plant parameters (PARAMS.toml)")
    p.add_argument("--hours", type=float, default=48.0, help="length of the simulated day")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--effect", default=None, help=f"one of {', '.join(EFFECTS)}")
    p.add_argument("--magnitude", type=float, default=None)
    p.add_argument("--speed", type=float, default=1.0,
                   help="time acceleration: 1 = real time, 60 = one plant minute per second")
    p.add_argument("--lab-dir", default=None,
                   help="drop lab results as JSON files into this folder when they are due")
    p.add_argument("--once", action="store_true", help="stop at the end of the day")
    p.set_defaults(func=_plant_server)
