"""``softsensor diagnose``: argument parsing, calibration on CAL, REPORT.json and the page.

    softsensor diagnose --calibrate-on CAL.mcap DAY.mcap --json REPORT.json [--report DIR]
    softsensor diagnose --params PARAMS.toml DAY.mcap --json REPORT.json [--report DIR]

With ``--calibrate-on`` the paper's calibration (:func:`softsensor.calibration.calibration_run.
calibrate`: the Optuna TPE study, then the Gauss-Newton polish) runs on CAL with ``--trials``
trials (default :data:`~softsensor.calibration.settings.DEFAULT_TRIALS`, 200 as the paper
and ``calibrate``: the same calibration whichever verb runs it) on its
``--window-hours`` window with the most natural variability. With ``--params`` the parameter
file is used as it is, its ``[discrepancy]`` (what the calibration left on held-out data,
written by ``softsensor calibrate``) sizing the calibration-error alternative of
:mod:`softsensor.diagnosis.calibration_error`; ``--calibrate-on`` carries its own
calibration's the same way.

REPORT.json (CONTRACT section 5) is written to ``--json`` (``-``: stdout, nothing else is
printed there); progress and the verdict line go to stderr. Every error is a one-line
:class:`~softsensor.errors.SoftsensorError`.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from softsensor.apps.loading import load_config_and_params, read_day_inputs
from softsensor.apps.verb_output import write_json
from softsensor.calibration.settings import DEFAULT_TRIALS
from softsensor.errors import ConfigError, require_packages
from softsensor.files import check_target
from softsensor.plantconfig import PARAMETER_NAMES
from softsensor.presentation.display import display_settings, lab_reference
from softsensor.presentation.verdicts import diagnosis_verdict, open_loop_sentence
from softsensor.signals import OUTPUT_NAMES

#: Calibration window taken from CAL. [h]
DEFAULT_CAL_WINDOW_HOURS = 48.0


def add_diagnose_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("day", metavar="DAY.mcap", help="recorded day to diagnose")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--calibrate-on", metavar="CAL.mcap", default=None,
                     help="recorded day to calibrate the model on first")
    src.add_argument("--params", metavar="PARAMS.toml", default=None,
                     help="use these calibrated parameters instead of calibrating")
    p.add_argument("--json", required=True, metavar="REPORT.json",
                   help="report file to write ('-': stdout)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write an HTML page with the figures to DIR")
    p.add_argument("--trials", type=int, default=DEFAULT_TRIALS,
                   help=f"Optuna trials of the calibration on CAL (default {DEFAULT_TRIALS})")
    p.add_argument("--seed", type=int, default=0, help="TPE seed of the calibration")
    p.add_argument("--window-hours", type=float, default=DEFAULT_CAL_WINDOW_HOURS,
                   help="calibration window taken from CAL [h] (default "
                        f"{DEFAULT_CAL_WINDOW_HOURS:g})")
    p.add_argument("--save-params", default=None, metavar="PARAMS.toml",
                   help="also write the parameters calibrated on CAL here")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--fit-fraction", type=float, default=None,
                   help="share of DAY, from its start, that the extension is fitted on; "
                        "the rest is held out to measure the gain (0.3 to 0.8, default 0.6)")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")


def _check_paths(args: argparse.Namespace) -> None:
    for name in ("day", "calibrate_on", "params"):
        v = getattr(args, name)
        if v is not None and not Path(v).is_file():
            flag = "DAY" if name == "day" else "--" + name.replace("_", "-")
            raise ConfigError(f"{flag} {v}: no such file")
    check_target(args.json)
    check_target(args.save_params, "--save-params")
    if args.trials < 1:
        raise ConfigError(f"--trials must be >= 1, got {args.trials}")
    if args.fit_fraction is not None and not 0.3 <= args.fit_fraction <= 0.8:
        raise ConfigError(f"--fit-fraction must be within [0.3, 0.8], got {args.fit_fraction}")


def diagnose_main(args: argparse.Namespace) -> int:
    """``softsensor diagnose``: calibrate (or load), diagnose, write REPORT.json (and DIR)."""
    require_packages("diagnose", "optuna", "matplotlib", "filterpy")
    from softsensor.calibration.open_loop_errors import open_loop_summary
    from softsensor.diagnosis.diagnose_day import diagnose
    from softsensor.diagnosis.problem import DEFAULT_FIT_FRACTION

    _check_paths(args)
    cfg = load_config_and_params(args).config
    t0 = time.perf_counter()
    calibration: dict[str, Any]
    normal, why_not = None, None
    if args.params:
        from softsensor.calibration.params_file import read_fit
        from softsensor.diagnosis.plant_normal import read_plant_normal

        fit = read_fit(args.params)
        normal, why_not = read_plant_normal(args.params)
        rmse = fit.get("rmse") if isinstance(fit.get("rmse"), dict) else None
        calibration = {"params_file": str(args.params), "rmse": rmse,
                       "discrepancy": cfg.extra.get("discrepancy")}
    else:
        cfg, calibration, fit = _calibrate(cfg, args)
    t_cal = time.perf_counter() - t0
    day = read_day_inputs(args.day)
    d = diagnose(cfg, day, source=str(args.day),
                 fit_fraction=args.fit_fraction or DEFAULT_FIT_FRACTION, normal=normal,
                 progress=None if args.quiet else _progress("diagnose"))
    doc = d.to_json()
    # the open-loop errors on the whole day, by the one function ``validate`` reports them with
    doc["open_loop"] = open_loop_summary(cfg, [d.problem.windows.segment], fit,
                                         d.problem.model)
    calibration["seconds"] = round(t_cal, 2)
    doc["calibration"] = calibration
    doc["timings_s"]["calibration"] = round(t_cal, 2)
    if args.report:
        from softsensor.presentation.diagnosis_report import write_report

        doc["report"] = str(write_report(d, args.report, doc))
    write_json(doc, args.json)
    if why_not and not args.quiet:
        print(f"diagnose: {why_not}", file=sys.stderr)
    x_ref = lab_reference([d.problem.windows])
    print(f"diagnose: {args.day}: cause {doc['cause']}"
          + (f" on {doc['channel']}" if doc.get("channel") else "")
          + f", held-out gain {doc['gain']:+.3f}. {diagnosis_verdict(doc)} "
          + open_loop_sentence(doc["open_loop"], x_ref, display_settings(cfg).moisture_basis),
          file=sys.stderr)
    return 0


def _progress(prefix: str) -> Callable[[str], None]:
    """A progress printer: one stderr line per phase, with the seconds since the first."""
    t0 = time.perf_counter()

    def say(phase: str) -> None:
        print(f"{prefix}: {phase} ... ({time.perf_counter() - t0:.0f} s)", file=sys.stderr,
              flush=True)

    return say


def _calibrate(cfg, args: argparse.Namespace
               ) -> tuple[Any, dict[str, Any], dict[str, Any]]:
    """Run the calibration pipeline on ``--calibrate-on``; the calibrated config, a summary
    for the report and the ``[fit]`` section a PARAMS.toml of it would hold."""
    import optuna

    from softsensor.apps.calibrate import load_segments
    from softsensor.calibration.calibration_run import calibrate
    from softsensor.calibration.optimize import StudySettings
    from softsensor.calibration.selection import DataSelection
    from softsensor.calibration.settings import calibration_settings

    if not args.window_hours > 0:
        raise ConfigError(f"--window-hours must be > 0, got {args.window_hours}")
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    segments, choices = load_segments([args.calibrate_on], cfg,
                                      DataSelection(window_hours=args.window_hours))
    for c in choices:
        print(f"diagnose: calibrate: {c.reason}", file=sys.stderr)
    settings = StudySettings(n_trials=args.trials, seed=args.seed, progress=False)
    result = calibrate(segments, cfg, settings, calibration_settings(cfg), choices=choices,
                       identify_result=False,
                       progress=None if args.quiet else _progress("diagnose: calibrate"))
    # what the calibration left on held-out data sizes the diagnosis's calibration-error
    # alternative, as it does through a PARAMS.toml's [discrepancy]
    cal_cfg = result.calibrated_config()
    disc = None if result.discrepancy is None else result.discrepancy.as_table()
    if args.save_params:
        from softsensor.calibration.params_file import params_document, write_params

        write_params(args.save_params, params_document(
            cfg, result.params, result.fit_section(), None, result.at_bounds, disc),
            "Calibrated by `softsensor diagnose --calibrate-on`.")
    summary = {
        "day": str(args.calibrate_on), "trials": args.trials, "seed": args.seed,
        "cost": result.fit.cost,
        "rmse": {n: result.fit.rmse[n] for n in OUTPUT_NAMES},
        "params": dict(zip(PARAMETER_NAMES, map(float, result.theta), strict=True)),
        "windows": [ch.segment.source for ch in choices],
        "discrepancy": disc,
    }
    return cal_cfg, summary, result.fit_section()


def add_learn_normal_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap",
                   help="the history days PARAMS.toml was calibrated on")
    p.add_argument("--params", required=True, metavar="PARAMS.toml",
                   help="calibrated parameters (with the history's [model_error])")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")


def learn_normal_main(args: argparse.Namespace) -> int:
    """``softsensor learn-normal``: diagnose and validate every history day against the
    plant's normal learned without it (:func:`~softsensor.diagnosis.plant_normal.
    learn_plant_normal`) and keep the result beside PARAMS.toml, where ``diagnose`` and
    ``validate`` judge every later day against it."""
    require_packages("learn-normal", "optuna")
    from softsensor.diagnosis.plant_normal import learn_plant_normal

    for v in [args.params, *args.days]:
        if not Path(v).is_file():
            raise ConfigError(f"{v}: no such file")
    cfg = load_config_and_params(args).config
    days = [read_day_inputs(p) for p in args.days]
    normal = learn_plant_normal(cfg, days, args.params, sources=[str(p) for p in args.days],
                                progress=None if args.quiet else _progress("learn-normal"))
    path = normal.write(args.params)
    named = [d.named for d in normal.days]
    print(f"learn-normal: {normal.n_days} history day(s) judged in {normal.seconds:.0f} s "
          f"(named on their own evidence: {', '.join(named)}); written to {path}",
          file=sys.stderr)
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``diagnose`` and ``learn-normal`` on the ``softsensor`` parser."""
    p = sub.add_parser("diagnose", help="find what the calibrated model gets wrong on a day")
    add_diagnose_arguments(p)
    p.set_defaults(func=diagnose_main)
    p = sub.add_parser("learn-normal", help="judge the history days of PARAMS.toml against "
                                            "a normal without each, for diagnose and validate")
    add_learn_normal_arguments(p)
    p.set_defaults(func=learn_normal_main)


__all__ = ["add_commands", "add_diagnose_arguments", "add_learn_normal_arguments",
           "diagnose_main", "learn_normal_main"]
