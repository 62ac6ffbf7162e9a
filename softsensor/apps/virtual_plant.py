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
import dataclasses
import logging
import signal
import sys
import time
from pathlib import Path

from softsensor.apps.loading import load_config_and_params
from softsensor.errors import ConfigError
from softsensor.files import writing
from softsensor.messages import iso_utc
from softsensor.plant.day import DEFAULT_START_NS, SimulatedDay
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


def simulate_plant(cfg: PlantConfig, args: argparse.Namespace, seed: int | None = None,
                   start_ns: int = DEFAULT_START_NS) -> SimulatedDay:
    """Run the plant chosen by ``args`` for ``args.hours`` from ``start_ns`` [ns since the
    epoch, UTC], with ``seed`` (default ``args.seed``)."""
    seed = args.seed if seed is None else seed
    if args.plant == "model":
        from softsensor.plant.simulator import simulate_day

        return simulate_day(cfg, args.hours, seed, args.effect, args.magnitude,
                            start_ns=start_ns)
    from softsensor.plant.independent import simulate_independent_day

    return simulate_independent_day(cfg, args.hours, seed, args.effect, args.magnitude,
                                    plant_seed=args.plant_seed, start_ns=start_ns)


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
    from softsensor.service.day_replay import parse_time

    start = parse_time(args.start, "--start")
    if args.days < 1:
        raise ConfigError(f"--days must be >= 1, got {args.days}")
    cfg = load_plant(args)
    if args.days == 1:
        day = simulate_plant(cfg, args, start_ns=start)
        with writing(args.out) as tmp:  # a run stopped half-way leaves no half file
            day.write(tmp)
        print(f"wrote {args.out}: {len(day.scans)} scans over {args.hours:g} h from "
              f"{iso_utc(start)}, {len(day.labs)} lab results, {_effect_words(day)}, seed "
              f"{args.seed}, {_plant_words(args)}", file=sys.stderr)
        return 0
    return _simulate_history(cfg, args, start)


def history_names(start_ns: int, hours: float, days: int) -> list[str]:
    """The file names of ``simulate --days``: each record's UTC start,
    ``2026-01-05T000000Z.mcap``, so that the names sort in time order (``calibrate
    DIR/*.mcap`` reads them so)."""
    step = round(hours * 3600e9)
    return [iso_utc(start_ns + i * step).replace(":", "").removesuffix("Z") + "Z.mcap"
            for i in range(days)]


def _simulate_history(cfg: PlantConfig, args: argparse.Namespace, start: int) -> int:
    """``--days N``: N consecutive records of ``--hours`` each into the folder ``--out``,
    record ``i`` with seed ``--seed + i`` from ``--start + i --hours``: a history to try
    ``calibrate`` on. Each record but the last is cut where the next begins, by log time (a
    simulated record ends with the scan at its end time, and lab results come in after
    their sample), as a historian's export split by day is; so the records do not overlap
    and ``replay`` takes them as one stream. Each file is written whole (no half file when
    stopped)."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: with --days {args.days}, --out is a folder for one "
                          f"file a record, and {out} is a file")
    step = round(args.hours * 3600e9)
    names = history_names(start, args.hours, args.days)
    scans = labs = 0
    for i, name in enumerate(names):
        day = simulate_plant(cfg, args, seed=args.seed + i, start_ns=start + i * step)
        if i < args.days - 1:
            day = _cut(day, start + (i + 1) * step)
        if i == 0:  # after the first record: bad --hours or --effect create no folder
            try:
                out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ConfigError(f"--out {out}: cannot create the folder: "
                                  f"{exc.strerror}") from exc
        with writing(out / name) as tmp:
            day.write(tmp)
        scans, labs = scans + len(day.scans), labs + len(day.labs)
        effect = _effect_words(day)
    print(f"wrote {args.days} consecutive records of {args.hours:g} h to {out}/ ({names[0]} "
          f"to {names[-1]}): {scans} scans, {labs} lab results, {effect}, seeds {args.seed} "
          f"to {args.seed + args.days - 1}, {_plant_words(args)}", file=sys.stderr)
    return 0


def _cut(day: SimulatedDay, end_ns: int) -> SimulatedDay:
    """``day`` without what was logged at or after ``end_ns`` [ns]."""
    return dataclasses.replace(day, scans=day.scans[day.scans.index < end_ns],
                               truth=day.truth[day.truth.index < end_ns],
                               labs=day.labs[day.labs["log_time_ns"] < end_ns]
                               .reset_index(drop=True))


def _effect_words(day: SimulatedDay) -> str:
    eff = day.effect
    return "clean day" if eff["effect"] == "none" else (
        f"effect {eff['effect']} magnitude {eff['magnitude']:g} {eff['unit']}"
        + (f" on {eff['channel']}" if eff.get("channel") else ""))


def _plant_words(args: argparse.Namespace) -> str:
    return ("plant independent, plant seed " + str(args.plant_seed)
            if args.plant == "independent" else "plant model")


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
    p.add_argument("--start", default=iso_utc(DEFAULT_START_NS),
                   help="first log time, ISO-8601 (UTC) or ns (default "
                        f"{iso_utc(DEFAULT_START_NS)})")
    p.add_argument("--days", type=int, default=1, metavar="N",
                   help="N consecutive records of --hours each, record i with seed --seed + i "
                        "from --start + i x --hours: a history for calibrate; --out is then a "
                        "folder, one file a record named by its UTC start "
                        "(2026-01-05T000000Z.mcap), which sort in time order (default 1)")
    p.add_argument("--out", required=True, metavar="DAY.mcap",
                   help="MCAP file to write (with --days N > 1: a folder)")
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
