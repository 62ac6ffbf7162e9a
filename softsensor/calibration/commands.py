"""``softsensor calibrate | identify | validate``: argument parsing and output only.

The work is done by :mod:`softsensor.calibration.pipeline`. ``calibrate`` and ``validate``
print one JSON document on stdout (progress and logging go to stderr); ``identify`` prints
the table of what the data can and cannot pin down and writes JSON with ``--json``. Errors are
:class:`~softsensor.errors.SoftsensorError` subclasses, which the ``softsensor`` command turns
into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.calibration.optimize import DEFAULT_STUDY_NAME, StudySettings
from softsensor.calibration.params_file import params_document, read_fit, write_params
from softsensor.calibration.pipeline import (
    DEFAULT_MIN_LABS,
    DEFAULT_WINDOW_HOURS,
    DataSelection,
    calibrate,
    identify_segments,
    load_segments,
    validate,
)
from softsensor.errors import ConfigError
from softsensor.jsonable import jsonable
from softsensor.plantconfig import (
    PARAMETER_NAMES,
    PlantConfig,
    load_parameters,
    load_plant_config,
)
from softsensor.signals import OUTPUT_NAMES


def _emit(doc: dict[str, Any], json_path: str | None) -> None:
    text = json.dumps(jsonable(doc), indent=2)
    if json_path:
        p = Path(json_path)
        if not p.parent.is_dir():
            raise ConfigError(f"--json {p}: directory {p.parent} does not exist")
        p.write_text(text + "\n", encoding="utf-8")
    print(text)


def _config(args: argparse.Namespace) -> PlantConfig:
    cfg = load_plant_config(args.config)
    if getattr(args, "params", None):
        cfg = load_parameters(args.params, cfg)
    return cfg


def _add_data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--window-hours", type=float, default=DEFAULT_WINDOW_HOURS,
                   help="calibration window [h]; a longer record is cut to the window(s) "
                        f"with the most natural variability (default {DEFAULT_WINDOW_HOURS:g})")
    p.add_argument("--windows-per-day", type=int, default=1,
                   help="non-overlapping windows to take from each day (default 1)")
    p.add_argument("--min-labs", type=int, default=DEFAULT_MIN_LABS,
                   help=f"lab samples a window must hold (default {DEFAULT_MIN_LABS})")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")


def _selection(args: argparse.Namespace) -> DataSelection:
    if not args.window_hours > 0:
        raise ConfigError(f"--window-hours must be > 0, got {args.window_hours}")
    if args.windows_per_day < 1:
        raise ConfigError(f"--windows-per-day must be >= 1, got {args.windows_per_day}")
    return DataSelection(args.window_hours, args.windows_per_day, max(args.min_labs, 1))


# ---------------------------------------------------------------------------- calibrate
def add_calibrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap", help="recorded day(s) to fit")
    p.add_argument("--trials", type=int, default=200,
                   help="finished trials the study should hold (default 200, as the paper); "
                        "an existing study is resumed up to this number")
    p.add_argument("--out", required=True, metavar="PARAMS.toml", help="file to write")
    p.add_argument("--seed", type=int, default=0, help="TPE seed (default 0)")
    p.add_argument("--storage", default=None, metavar="URL",
                   help="Optuna storage shared by workers: journal:PATH, a .log file, "
                        "sqlite:///f.db, postgresql://... (default: in memory)")
    p.add_argument("--study-name", default=DEFAULT_STUDY_NAME,
                   help=f"study in the storage (default {DEFAULT_STUDY_NAME})")
    p.add_argument("--batch", type=int, default=1,
                   help="trials simulated together in one batched model call (default 1)")
    p.add_argument("--chunks", type=int, default=4,
                   help="horizon chunks with a partial cost for pruning (default 4)")
    p.add_argument("--no-prune", action="store_true", help="never prune trials")
    p.add_argument("--no-polish", action="store_true",
                   help="skip the local Gauss-Newton polish of the best trial")
    p.add_argument("--no-identify", action="store_true",
                   help="skip the identifiability analysis of the result")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write figures and a Markdown page to DIR")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the JSON here")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_data_arguments(p)


def calibrate_main(args: argparse.Namespace) -> int:
    """``softsensor calibrate``: fit, write PARAMS.toml, print a JSON summary."""
    config = _config(args)
    out = Path(args.out)
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: directory {out.parent} does not exist")
    settings = StudySettings(n_trials=args.trials, seed=args.seed, storage=args.storage,
                             study_name=args.study_name, n_chunks=args.chunks,
                             batch=args.batch, prune=not args.no_prune,
                             progress=not args.quiet and sys.stderr is not None)
    settings.check()
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)  # the progress bar says enough
    segments, choices = load_segments(args.days, config, _selection(args))
    for c in choices:
        print(f"calibrate: {c.reason}", file=sys.stderr)
    result = calibrate(segments, config, settings, choices=choices,
                       polish=not args.no_polish, identify=not args.no_identify)
    verdicts = None
    if result.identifiability is not None:
        verdicts = {v.name: v.verdict for v in result.identifiability.verdicts}
    doc = params_document(config, result.params, result.fit_section(), verdicts)
    comment = ("Calibrated by `softsensor calibrate` (paper eq. 4, Table 1 bounds).\n"
               "Load with softsensor.plantconfig.load_parameters or --params.")
    write_params(out, doc, comment)
    summary = {"out": str(out), **result.summary()}
    if args.report:
        from softsensor.calibration.report import calibration_page

        summary["report"] = str(calibration_page(result, args.report))
    _emit(summary, args.json)
    return 0


# ---------------------------------------------------------------------------- identify
def add_identify_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap", help="recorded day(s)")
    p.add_argument("--params", default=None, metavar="PARAMS.toml",
                   help="parameters to analyse at (default: the config's values)")
    p.add_argument("--storage", default=None, metavar="URL",
                   help="the calibration study, for parameter importance (Fig. 4)")
    p.add_argument("--study-name", default=DEFAULT_STUDY_NAME)
    p.add_argument("--importance", default="ped-anova", choices=("ped-anova", "fanova"),
                   help="importance evaluator (fanova, the paper's, needs scikit-learn)")
    p.add_argument("--json", default=None, metavar="FILE", help="write the full analysis")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write figures and a Markdown page to DIR")
    _add_data_arguments(p)


def identify_main(args: argparse.Namespace) -> int:
    """``softsensor identify``: sensitivities, FIM, correlations, verdicts."""
    from softsensor.calibration.report import identifiability_table, identify_page
    from softsensor.model import DryerModel

    config = _config(args)
    segments, choices = load_segments(args.days, config, _selection(args))
    model = DryerModel(config)
    theta = config.parameter_vector()
    ident, sens = identify_segments(model, segments, theta, config)
    study = importance = None
    if args.storage:
        import optuna

        from softsensor.calibration.identifiability import parameter_importance
        from softsensor.calibration.optimize import open_storage

        try:
            study = optuna.load_study(study_name=args.study_name,
                                      storage=open_storage(args.storage))
        except KeyError as exc:
            raise ConfigError(f"--storage {args.storage}: no study {args.study_name!r}") from exc
        importance = parameter_importance(study, args.importance)
    print(identifiability_table(ident, config, importance))
    print(f"\nweighted FIM (Table 3 form) condition number {ident.condition_number:.3g}; "
          f"identifiable: {', '.join(ident.identifiable) or 'none'}; poorly identifiable: "
          f"{', '.join(ident.poorly_identifiable) or 'none'}")
    doc = {
        "windows": [c.reason for c in choices],
        "params": dict(zip(PARAMETER_NAMES, map(float, theta), strict=True)),
        "verdicts": {v.name: {"verdict": v.verdict, "relative_se": v.relative_se,
                              "posterior_over_prior": v.prior_ratio,
                              "most_correlated": v.partner, "correlation": v.correlation,
                              "eq4_se": v.eq4_se,
                              "reason": v.reason} for v in ident.verdicts},
        "fim": ident.fim.tolist(), "fim_condition_number": ident.condition_number,
        "fim_eigenvalues": ident.eigenvalues.tolist(),
        "fim_eigenvectors": ident.eigenvectors.tolist(),
        "correlation": ident.correlation.tolist(), "noise": ident.noise.tolist(),
        "relative_sensitivity_mean_abs": {
            out: dict(zip(PARAMETER_NAMES, map(float, np.mean(np.concatenate(
                [np.abs(s.relative[:, c, :]) for s in sens]), axis=0)), strict=True))
            for c, out in enumerate(OUTPUT_NAMES)},
        "weakest_directions": ident.weakest_directions(2),
        "importance": importance,
    }
    if args.report:
        doc["report"] = str(identify_page(ident, sens[0], config, theta, args.report, study,
                                          importance))
    if args.json:
        p = Path(args.json)
        if not p.parent.is_dir():
            raise ConfigError(f"--json {p}: directory {p.parent} does not exist")
        p.write_text(json.dumps(jsonable(doc), indent=2) + "\n", encoding="utf-8")
    return 0


# ---------------------------------------------------------------------------- validate
def add_validate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("day", metavar="DAY.mcap", help="an independent recorded day")
    p.add_argument("--params", required=True, metavar="PARAMS.toml",
                   help="calibrated parameters")
    p.add_argument("--json", default=None, metavar="FILE", help="also write the JSON here")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write Fig. 6 and a Markdown page to DIR")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")


def validate_main(args: argparse.Namespace) -> int:
    """``softsensor validate``: per-channel RMSE and eq. 4 cost on a whole day."""
    from softsensor.calibration.dataset import load_segment

    config = _config(args)
    cal_cost = read_fit(args.params).get("cost")
    segment = load_segment(args.day, config)
    result = validate(segment, config, float(cal_cost) if isinstance(cal_cost, (int, float))
                      else None)
    doc = result.summary()
    if args.report:
        from softsensor.calibration.report import validation_page

        doc["report"] = str(validation_page(result, config, args.report))
    _emit(doc, args.json)
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``calibrate``, ``identify`` and ``validate`` on the ``softsensor`` parser."""
    p = sub.add_parser("calibrate", help="fit the seven Table 1 parameters to recorded days")
    add_calibrate_arguments(p)
    p.set_defaults(func=calibrate_main)
    p = sub.add_parser("identify", help="which parameters the data can pin down (FIM)")
    add_identify_arguments(p)
    p.set_defaults(func=identify_main)
    p = sub.add_parser("validate", help="RMSE and eq. 4 cost of PARAMS.toml on another day")
    add_validate_arguments(p)
    p.set_defaults(func=validate_main)


__all__ = ["add_calibrate_arguments", "add_commands", "add_identify_arguments",
           "add_validate_arguments", "calibrate_main", "identify_main", "validate_main"]
