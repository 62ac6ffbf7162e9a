"""``softsensor run`` (the daemon) and ``softsensor replay`` (the streaming path, offline).

Both verbs only parse options, load and validate the configuration once, and hand over to
:class:`~softsensor.service.daemon.Daemon` or
:func:`~softsensor.service.offline_replay.replay_to_file`. Command-line options override the
config's ``[service]`` table. Bad input ends in one line on stderr and exit status 2 (the
error classes of :mod:`softsensor.errors`, printed by :mod:`softsensor.cli`).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from softsensor.apps.loading import load_config_and_params
from softsensor.errors import ConfigError, IngestError
from softsensor.plantconfig import PlantConfig

if TYPE_CHECKING:  # the service is imported when a verb runs, not when the CLI starts
    from softsensor.service.settings import ServiceSettings

log = logging.getLogger(__name__)


def _plc(value: str | None) -> tuple[str | None, int | None]:
    if value is None:
        return None, None
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--plc must look like HOST:PORT, got {value!r}")
    return host, int(port)


# ----------------------------------------------------------------------------------------------
# run


def run_settings(args: argparse.Namespace
                 ) -> tuple[PlantConfig, PlantConfig, ServiceSettings]:
    """What ``softsensor run`` runs on: the config as written, the config with ``--params``,
    and the ``[service]`` table with the command line's overrides. The table and the tag map
    beside it come from the config file (``--params`` carries neither)."""
    from softsensor.service.settings import service_settings

    base, cfg = load_config_and_params(args)
    host, port = _plc(args.plc)
    settings = service_settings(base).with_overrides(
        unit=args.unit, tagmap=args.tagmap, plc_host=host, plc_port=port,
        data_dir=args.data_dir, checkpoint=args.checkpoint, lab_dir=args.lab_dir,
        zenoh_mode=args.mode, zenoh_listen=args.listen, zenoh_connect=args.connect,
        time_scale=args.time_scale, clock_start=args.clock_start,
        record=False if args.no_record else None, log_format=args.log_format)
    return base, cfg, settings


def _run(args: argparse.Namespace) -> int:
    from softsensor.service.heap import limit_arenas

    limit_arenas()  # before any thread of the daemon's libraries is started
    from softsensor.ingest.tagmap import DEFAULT_TAGMAP
    from softsensor.service.daemon import Daemon, DaemonInfo
    from softsensor.service.logs import configure_logging

    base, cfg, settings = run_settings(args)
    configure_logging(settings.log_format)
    daemon = Daemon(cfg, settings, kind=args.estimator,
                    resume=False if args.no_resume else args.resume)

    def _ready(info: DaemonInfo) -> None:
        print(f"softsensor run: unit={info.unit} estimator={info.estimator} "
              f"zenoh={','.join(info.endpoints) or 'none'} plc={info.plc} "
              f"data_dir={info.data_dir} resumed={str(info.resumed).lower()} "
              f"config={base.source} params={args.params or 'none'} "
              f"tagmap={settings.tagmap or DEFAULT_TAGMAP} "
              f"outputs={','.join(info.outputs) or 'none'}", flush=True)

    async def _main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(signum, stop.set)  # the handlers only set the flag
        await daemon.run(stop, ready=_ready)

    asyncio.run(_main())
    print("softsensor run: stopped", flush=True)
    return 0


def _add_run(sub: argparse._SubParsersAction) -> None:
    from softsensor.estimation.settings import ESTIMATOR_KINDS
    from softsensor.service.settings import LOG_FORMATS, ZENOH_MODES

    p = sub.add_parser("run", help="the estimator daemon: poll the PLC, estimate, publish, "
                                   "record (until SIGTERM/SIGINT)")
    p.add_argument("--config", default=None, help="plant config with a [service] table "
                                                  "(default: built-in dryer1)")
    p.add_argument("--params", default=None, help="calibrated parameters (PARAMS.toml)")
    p.add_argument("--unit", default=None, help="unit name in keys and files")
    p.add_argument("--tagmap", default=None, help="Modbus tag map TOML")
    p.add_argument("--plc", default=None, metavar="HOST:PORT", help="PLC endpoint override")
    p.add_argument("--data-dir", default=None, help="folder of the daily MCAP recordings")
    p.add_argument("--checkpoint", default=None, help="estimator checkpoint file")
    p.add_argument("--lab-dir", default=None, help="watched lab drop folder")
    p.add_argument("--mode", default=None, choices=ZENOH_MODES, help="Zenoh session mode")
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="Zenoh listen endpoint, repeatable (default tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to (e.g. a router), repeatable")
    p.add_argument("--estimator", default=None, choices=ESTIMATOR_KINDS,
                   help="estimator (default: the config's estimator.kind, ukf)")
    p.add_argument("--time-scale", type=float, default=None,
                   help="clock speed-up for accelerated demos (match plant-server --speed)")
    p.add_argument("--clock-start", default=None, metavar="TIME|plc",
                   help="start of the scaled clock, ISO-8601 or ns (default now); plc: the "
                        "PLC's clock (the tag map's [clock] registers, which plant-server "
                        "serves), so a demo's plant and daemon share one clock")
    p.add_argument("--no-record", action="store_true", help="do not record MCAP files")
    p.add_argument("--no-resume", action="store_true", help="ignore the checkpoint")
    p.add_argument("--resume", default="auto", choices=("auto", "required"),
                   help="auto (default): a checkpoint that fails its checks is moved aside "
                        "and the daemon starts afresh; required: stop with an error instead")
    p.add_argument("--log-format", default=None, choices=LOG_FORMATS,
                   help="kv: key=value lines (default); json: one JSON object a line "
                        "(service.log_format)")
    p.set_defaults(func=_run)


# ----------------------------------------------------------------------------------------------
# replay


def _replay(args: argparse.Namespace) -> int:
    from softsensor.service.day_replay import parse_rate
    from softsensor.service.offline_replay import replay_to_file
    from softsensor.service.settings import service_settings

    parse_rate(args.rate)  # a bad rate fails before anything starts
    cfg = load_config_and_params(args).config
    settings = service_settings(cfg)
    if not getattr(args, "verbose", False):
        for name in ("softsensor.service", "softsensor.estimation", "softsensor.ingest"):
            logging.getLogger(name).setLevel(logging.WARNING)
    summary = replay_to_file(args.days, args.out, cfg, estimator=args.estimator, rate=args.rate,
                             start=args.start, end=args.end,
                             allow_truncated=args.allow_truncated, settings=settings,
                             progress=None if args.quiet else _every(5.0),
                             checkpoint_in=args.checkpoint_in,
                             checkpoint_out=args.checkpoint_out, via_zenoh=args.via_zenoh)
    print(summary.line(), file=sys.stderr, flush=True)
    problem = summary.problem()
    if problem is not None and problem[0] == "error":
        raise IngestError(problem[1] + f" ({args.out} is kept)")
    if problem is not None:
        print(f"warning: {problem[1]}", file=sys.stderr, flush=True)
    return 0


def _every(seconds: float) -> Callable[[int, int], None]:
    """A replay progress printer: one stderr line at most every ``seconds`` of wall time."""
    from softsensor.messages import iso_utc

    last = [time.monotonic()]

    def show(window_end_ns: int, ticks: int) -> None:
        now = time.monotonic()
        if now - last[0] >= seconds:
            last[0] = now
            print(f"replay: {ticks} ticks, at {iso_utc(window_end_ns)} ...", file=sys.stderr,
                  flush=True)

    return show


def _add_replay(sub: argparse._SubParsersAction) -> None:
    from softsensor.estimation.settings import ESTIMATOR_KINDS

    p = sub.add_parser("replay", help="replay recorded days through the estimator into one "
                                      "MCAP file")
    p.add_argument("days", nargs="+", metavar="DAY.mcap",
                   help="recorded day(s), in time order: several run as one stream, the "
                        "estimator's state carried across them as the daemon does")
    p.add_argument("--params", default=None,
                   help="calibrated parameters (PARAMS.toml; default: the config's values)")
    p.add_argument("--out", required=True, metavar="EST.mcap",
                   help="MCAP file to write (inputs, estimates, health)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--estimator", default=None, choices=ESTIMATOR_KINDS,
                   help="estimator (default: the config's estimator.kind, ukf)")
    p.add_argument("--rate", default="max",
                   help="speed-up over real time (1 = real time) or 'max' (default)")
    p.add_argument("--start", default=None, help="first log time, ISO-8601 (UTC) or ns")
    p.add_argument("--end", default=None, help="end log time (excluded), ISO-8601 or ns")
    p.add_argument("--allow-truncated", action="store_true",
                   help="replay the intact part of a truncated file")
    p.add_argument("--checkpoint-in", default=None, metavar="FILE",
                   help="start the estimator from this checkpoint (the daemon's format)")
    p.add_argument("--checkpoint-out", default=None, metavar="FILE",
                   help="leave the estimator's checkpoint here (before the last partial "
                        "window is flushed): the next day's replay starts from it")
    p.add_argument("--via-zenoh", action="store_true",
                   help="go over two Zenoh sessions on loopback, as the daemon's bus does, "
                        "instead of in memory (the same estimates, slower)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=_replay)


# ----------------------------------------------------------------------------------------------
# health


def _health(args: argparse.Namespace) -> int:
    """``softsensor health``: ask a running daemon's health queryable; exit 0 when it answers
    and its estimator thread is not stalled, 1 otherwise (a container's HEALTHCHECK). The
    whole call, connecting included, takes about ``--timeout`` at most; an answer that cannot
    be attributed to the daemon (:func:`~softsensor.service.watchdog.query_health`) is none."""
    from softsensor.bus.zenoh_bus import open_session
    from softsensor.service.settings import (
        UNIT_NAME,
        UNIT_RULE,
        bus_options,
        resolve_unit,
        service_settings,
    )
    from softsensor.service.watchdog import query_health

    if not 0 < args.timeout <= 600:
        raise ConfigError(f"--timeout must be in (0, 600] s, got {args.timeout}")
    cfg = load_config_and_params(args).config
    settings = service_settings(cfg)
    if args.unit is not None and not UNIT_NAME.fullmatch(args.unit):
        raise ConfigError(f"--unit {args.unit!r} {UNIT_RULE}")
    unit = args.unit or resolve_unit(settings, cfg)
    connect = args.connect or [ep.replace("0.0.0.0", "127.0.0.1") for ep in settings.listen]
    if not connect:
        raise ConfigError("health: give --connect ENDPOINT (the config's service listens "
                          "nowhere)")
    auth = {k: v for k, v in bus_options(settings, unit).items() if k in ("user", "password")}
    deadline = time.monotonic() + args.timeout
    try:
        session = open_session(mode="client", connect=list(connect),
                               open_timeout_s=args.timeout, **auth)
    except ConfigError as exc:  # refused or nobody there: unhealthy, not a usage error
        print(f"softsensor health: {unit}: {exc}", file=sys.stderr)
        return 1
    with session:
        answer = query_health(session, unit, max(deadline - time.monotonic(), 0.2))
    doc = answer.doc
    if doc is None:
        print(f"softsensor health: {unit}: {', '.join(connect)}: {answer.problem}",
              file=sys.stderr)
        return 1
    if args.json:
        from softsensor.apps.verb_output import write_json

        write_json(doc, args.json)
    age = doc.get("last_tick_age_s")
    print(f"softsensor health: {unit}: {doc.get('status')}"
          + (" (STALLED)" if doc.get("stalled") else "")
          + f": {doc.get('detail')}"
          + ("" if age is None else f"; last estimate {age:.0f} s ago"), file=sys.stderr)
    return 1 if doc.get("stalled") else 0


def _add_health(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("health", help="ask a running daemon for its health (exit 1 when it "
                                      "does not answer or its estimator is stalled)")
    p.add_argument("--config", default=None, help="the daemon's plant config (unit, bus "
                                                  "credentials; default: built-in dryer1)")
    p.add_argument("--unit", default=None, help="unit name (default: the config's)")
    p.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="the daemon's Zenoh endpoint (default: its [service] listen "
                        "endpoints on loopback)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait (default 5)")
    p.add_argument("--json", default=None, metavar="FILE",
                   help="write the daemon's answer here ('-': stdout)")
    p.set_defaults(func=_health)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register the ``run``, ``replay`` and ``health`` verbs (called by
    :mod:`softsensor.cli`)."""
    _add_run(sub)
    _add_replay(sub)
    _add_health(sub)
