"""``softsensor advise``: the outlet-temperature set point that holds the target outlet
moisture at the least heat, from a recorded day and the calibrated parameters.

``softsensor advise DAY.mcap --params PARAMS.toml`` gives the advice at the day's last hour
(or one line saying why there is none); ``softsensor advise --history DAY.mcap ... --params
PARAMS.toml`` replays every hour of the days and sums what following the advice would have
changed (:mod:`softsensor.advisor.replay`), with a figure (``--figure``, the offline extra).
A DAY.mcap without estimates (a recorded day) is first run through the streaming path
(``softsensor replay``, the days in time order as one stream); a recording of the replay or
of the daemon is read as it is.

The parameters' covariance comes from ``--identify IDENT.json`` (the JSON of ``softsensor
identify``: relative standard errors and correlations in ln(theta)), else from the same
analysis run here on the (first) day, without its profile test. Advisory only: nothing is
written to the PLC.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.apps.loading import load_config_and_params
from softsensor.apps.verb_output import say, write_json
from softsensor.errors import ConfigError, IngestError, require_packages
from softsensor.files import check_target
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN

VERB = "advise"


def covariance_on_day(day: str | Path, base: PlantConfig, config: PlantConfig) -> np.ndarray:
    """The identifiability analysis (:func:`~softsensor.calibration.identifiability.identify`,
    no profile test) of the parameters on ``day``: their posterior covariance in ln(theta)."""
    from softsensor.apps.calibrate import load_segments
    from softsensor.calibration.calibration_run import objective_spec
    from softsensor.calibration.identifiability import identify
    from softsensor.calibration.settings import calibration_settings
    from softsensor.model import DryerModel

    segments, _ = load_segments([day], config)
    model = DryerModel(config)
    spec = objective_spec(model, segments, base, calibration_settings(base))
    ident, _ = identify(model, segments, config.parameter_vector(), spec, config.bounds(),
                        profile=False)
    return np.asarray(ident.covariance, float)


def _has_estimates(path: Path) -> bool:
    from softsensor.recording.mcap_day import iter_messages

    return next(iter(iter_messages(path, topics=[TOPIC_ESTIMATE])), None) is not None


def recordings(days: Sequence[str], config: PlantConfig, tmp: Path) -> list[Path]:
    """The recordings to read: each day as it is when it holds estimates, else all such days
    replayed through the streaming path as one stream into ``tmp``."""
    paths = [Path(d) for d in days]
    for p in paths:
        if not p.is_file():
            raise IngestError(f"{p}: no such file")
    raw = [p for p in paths if not _has_estimates(p)]
    if not raw:
        return paths
    if len(raw) != len(paths):
        raise ConfigError("give either recorded days or estimates recordings, not both")
    from softsensor.service.offline_replay import replay_to_file

    out = tmp / "estimates.mcap"
    say(VERB, f"replaying {len(raw)} day(s) through the estimator first")
    replay_to_file(raw, out, config)
    return [out]


def load_situations(paths: Sequence[Path], cfg, every: float) -> list:
    """The situations (:func:`softsensor.advisor.replay.situations`) of the recordings."""
    from softsensor.advisor.replay import situations
    from softsensor.recording.mcap_day import iter_messages, read_day

    out = []
    for p in paths:
        day = read_day(p, topics=[TOPIC_SCAN, TOPIC_LAB])
        est, health = [], []
        for topic, t, body in iter_messages(p, topics=[TOPIC_ESTIMATE, TOPIC_HEALTH]):
            (est if topic == TOPIC_ESTIMATE else health).append((t, body))
        if not est:
            raise IngestError(f"{p}: no {TOPIC_ESTIMATE} messages")
        out.extend(situations(day.scans, est, health, cfg, every))
    return out


def _main(args: argparse.Namespace) -> int:
    from softsensor.advisor.advice import Envelope, advise
    from softsensor.advisor.replay import what_if
    from softsensor.advisor.settings import advisor_settings
    from softsensor.estimation.model_error import model_error_of
    from softsensor.model import DryerModel

    if (args.day is None) == (args.history is None):
        raise ConfigError("give one DAY.mcap, or --history DAY.mcap ...")
    if args.figure is not None:
        require_packages("advise --figure", "matplotlib")
    check_target(args.json)
    check_target(args.figure, "--figure")
    if not args.every > 0:
        raise ConfigError(f"--every must be > 0, got {args.every}")
    base, config = load_config_and_params(args)
    settings = advisor_settings(config)
    me = model_error_of(config)
    if me is None:
        raise ConfigError(f"{args.params}: no [model_error] table: the advisor needs the "
                          "history's operating envelope (calibrate from history)")
    env = Envelope.of(me, settings.envelope_sd)
    days = [args.day] if args.day is not None else list(args.history)
    with tempfile.TemporaryDirectory(prefix="softsensor-advise-") as tmp:
        paths = recordings(days, config, Path(tmp))
        if args.identify is not None:
            from softsensor.service.advisor_tap import covariance_from_identify

            cov, cov_source = covariance_from_identify(args.identify), str(args.identify)
        else:
            say(VERB, f"the parameters' covariance: identifiability analysis on {paths[0]}")
            cov = covariance_on_day(paths[0], base, config)
            cov_source = f"identify on {days[0]} (no profile test)"
        sits = load_situations(paths, settings, args.every)
    if not sits:
        raise IngestError(f"{days[0]}: no estimate ticks to advise on")
    model = DryerModel(config)
    theta = config.parameter_vector()
    if args.day is not None:
        sits = sits[-1:]
    advices = [advise(model, theta, cov, s, settings, env) for s in sits]
    doc: dict[str, Any] = {
        "settings": {"moisture_target": settings.moisture_target,
                     "moisture_max": settings.moisture_max,
                     "confidence": settings.confidence},
        "envelope": {"low": dict(env.low), "high": dict(env.high)},
        "covariance_source": cov_source,
        "parameter_se": dict(zip(PARAMETER_NAMES, np.sqrt(np.diag(cov)).tolist(), strict=True)),
    }
    if args.day is not None:
        a = advices[0]
        doc["advice"] = a.to_body()
        write_json(doc, args.json)
        say(VERB, ("advice: " if a.advised else "no advice: ") + a.reason)
        return 0
    w = what_if(advices, sits, settings, args.every)
    doc["what_if"] = w.to_body()
    doc["hours"] = [a.to_body() for a in advices]
    write_json(doc, args.json)
    if args.figure is not None:
        from softsensor.presentation.advice_figures import what_if_figure

        what_if_figure(advices, sits, settings, args.figure)
    say(VERB, f"{w.hours_advised} of {w.hours} hours advised; following the advice "
              f"{'saves' if w.energy_saved_kwh >= 0 else 'costs'} "
              f"{abs(w.energy_saved_kwh):.0f} kWh ({abs(w.saved_kwh_per_t):.1f} kWh/t) over "
              f"them; expected {w.expected_hours_above_max:.2f} h above "
              f"{settings.moisture_max:g} kg/kg (as run: {w.hours_above_max_as_run} h); "
              f"refused: {', '.join(f'{k} {n}' for k, n in w.refusals.items()) or 'none'}")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register the ``advise`` verb (called by :mod:`softsensor.cli`)."""
    p = sub.add_parser("advise", help="advise the outlet-temperature set point that holds the "
                                      "target moisture at the least heat (advisory only)")
    p.add_argument("day", nargs="?", default=None, metavar="DAY.mcap",
                   help="a recorded day or an estimates recording: the advice at its last hour")
    p.add_argument("--history", nargs="+", default=None, metavar="DAY.mcap",
                   help="the what-if: every hour of these days (in time order)")
    p.add_argument("--params", required=True, metavar="PARAMS.toml",
                   help="calibrated parameters with their [model_error] (the envelope)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--identify", default=None, metavar="IDENT.json",
                   help="the parameters' covariance from softsensor identify --json "
                        "(default: that analysis run here on the first day)")
    p.add_argument("--every", type=float, default=3600.0, metavar="S",
                   help="seconds between advices of the what-if (default 3600)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the advice here ('-': "
                                                                "stdout)")
    p.add_argument("--figure", default=None, metavar="FIG.png",
                   help="the what-if's figure (needs matplotlib, the offline extra)")
    p.set_defaults(func=_main)


__all__ = ["add_commands", "covariance_on_day", "load_situations",
           "recordings"]
