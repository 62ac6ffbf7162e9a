"""``softsensor calibrate | identify | validate``: argument parsing and output only.

The work is done by :mod:`softsensor.calibration.calibration_run`; the pages by
:mod:`softsensor.presentation.calibration_report`. ``calibrate`` and ``validate``
print one JSON document on stdout (progress and logging go to stderr); ``identify`` prints
the table of what the data can and cannot pin down and writes JSON with ``--json``. Errors are
:class:`~softsensor.errors.SoftsensorError` subclasses, which the ``softsensor`` command turns
into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.apps.loading import load_config_and_params, read_day_inputs
from softsensor.apps.verb_output import write_json
from softsensor.calibration.dataset import Segment, segment_from_day
from softsensor.calibration.identifiability import PAPER_CONDITION_NUMBER
from softsensor.calibration.params_file import params_document, read_fit, write_params
from softsensor.calibration.selection import (
    DEFAULT_MIN_LABS,
    DEFAULT_WINDOW_HOURS,
    DataSelection,
    WindowChoice,
)
from softsensor.calibration.settings import (
    COSTS,
    DEFAULT_STUDY_NAME,
    DEFAULT_TRIALS,
    INLET_MODES,
    CalibrationSettings,
    calibration_settings,
)
from softsensor.errors import ConfigError, require_packages
from softsensor.files import check_target
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig
from softsensor.presentation.display import display_settings, moisture_pct_points
from softsensor.recording.mcap_day import RecordedDay
from softsensor.signals import OUTPUT_NAMES


def _add_data_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--window-hours", type=float, default=None,
                   help="calibration window [h]; a longer record is cut to the window(s) "
                        f"with the most natural variability (default {DEFAULT_WINDOW_HOURS:g} "
                        f"for one day, {HISTORY_WINDOW_HOURS:g} for several)")
    p.add_argument("--windows-per-day", type=int, default=1,
                   help="non-overlapping windows to take from a single day (default 1; "
                        "several days: windows are picked across them up to --fit-hours)")
    p.add_argument("--min-labs", type=int, default=DEFAULT_MIN_LABS,
                   help=f"lab samples a window must hold (default {DEFAULT_MIN_LABS})")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")


#: Calibration window across several days of history [h], and the hours of them fitted.
HISTORY_WINDOW_HOURS = 12.0
HISTORY_FIT_HOURS = 96.0


def default_window_hours(n_days: int) -> float:
    """The verb's default calibration window [h]: the paper's 48 h for one day, shorter
    windows picked across the days of a history."""
    return DEFAULT_WINDOW_HOURS if n_days == 1 else HISTORY_WINDOW_HOURS


def default_structure(base: PlantConfig, n_days: int, asked: bool | None = None) -> list[Any]:
    """The structural alternatives the verb searches: the default library with several days
    (or when ``asked``), none with one day (or when not)."""
    from softsensor.calibration.structure_search import default_library

    on = n_days > 1 if asked is None else asked
    return default_library(base) if on else []


def _window_hours(args: argparse.Namespace) -> float:
    """``--window-hours``, else :func:`default_window_hours`."""
    if args.window_hours is None:
        return default_window_hours(len(args.days))
    return args.window_hours


def _selection(args: argparse.Namespace) -> DataSelection:
    args.window_hours = _window_hours(args)
    if not args.window_hours > 0:
        raise ConfigError(f"--window-hours must be > 0, got {args.window_hours}")
    if args.windows_per_day < 1:
        raise ConfigError(f"--windows-per-day must be >= 1, got {args.windows_per_day}")
    return DataSelection(args.window_hours, args.windows_per_day, max(args.min_labs, 1))


def load_segment(path: str | Path, config: PlantConfig) -> Segment:
    """Read a recorded day and resample it to model windows (:mod:`.loading`)."""
    return segment_from_day(read_day_inputs(path), config, source=str(path))


def load_segments(paths: Sequence[str | Path], config: PlantConfig,
                  selection: DataSelection | None = None
                  ) -> tuple[list[Segment], list[WindowChoice]]:
    """Read every day, one at a time, and pick its calibration window(s) (``selection``
    default: :class:`DataSelection`'s)."""
    from softsensor.calibration.selection import select_segments

    def days() -> Iterator[tuple[str, RecordedDay]]:
        for p in paths:
            yield str(p), read_day_inputs(p)

    return select_segments(days(), config, selection or DataSelection())


# ---------------------------------------------------------------------------- calibrate
def _add_objective_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cost", choices=COSTS, default=None,
                   help="eq4 (the paper's weighted RMSE sum) or likelihood (each channel by "
                        "its own noise); default: [calibration] cost, else likelihood")
    p.add_argument("--inlet", choices=INLET_MODES, default=None,
                   help="the unmeasured inlet moisture: estimated (a slow trajectory fitted "
                        "per day, default) or nominal (the paper's)")
    p.add_argument("--prior-sigma", type=float, default=None,
                   help="sd of the prior on ln(theta) around the config's values (default 1)")
    p.add_argument("--no-prior", action="store_true", help="no prior: the plain bounded fit")
    p.add_argument("--paper", action="store_true",
                   help="the paper's calibration: eq4, nominal inlet moisture, no prior")


def _calibration_settings(args: argparse.Namespace, config: PlantConfig
                          ) -> CalibrationSettings:
    s = calibration_settings(config)
    changes: dict[str, Any] = {}
    if getattr(args, "paper", False):
        changes.update(cost="eq4", inlet="nominal", prior=False)
    if getattr(args, "cost", None):
        changes["cost"] = args.cost
    if getattr(args, "inlet", None):
        changes["inlet"] = args.inlet
    if getattr(args, "prior_sigma", None) is not None:
        if not (args.prior_sigma > 0 and np.isfinite(args.prior_sigma)):
            raise ConfigError(f"--prior-sigma must be > 0, got {args.prior_sigma}")
        changes["prior_sigma"] = float(args.prior_sigma)
    if getattr(args, "no_prior", False):
        changes["prior"] = False
    if getattr(args, "holdout", None) is not None:
        if not 0.0 <= args.holdout < 0.9:
            raise ConfigError(f"--holdout must be in [0, 0.9), got {args.holdout}")
        changes["holdout_fraction"] = float(args.holdout)
    return dataclasses.replace(s, **changes)


def add_calibrate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap", help="recorded day(s) to fit")
    p.add_argument("--trials", type=int, default=DEFAULT_TRIALS,
                   help=f"finished trials the study should hold (default {DEFAULT_TRIALS}, as "
                        "the paper); "
                        "an existing study is resumed up to this number")
    p.add_argument("--out", required=True, metavar="PARAMS.toml", help="file to write")
    p.add_argument("--params", default=None, metavar="PARAMS.toml",
                   help="the current parameters, which the result must beat on the "
                        "validation data (default: the config's values)")
    p.add_argument("--validate-on", nargs="+", default=None, metavar="DAY.mcap",
                   help="validate on these days (default: the last --holdout share of the "
                        "calibration data)")
    p.add_argument("--holdout", type=float, default=None,
                   help="share of each calibration window held out to validate on "
                        "(default 0.25; 0: none)")
    p.add_argument("--fit-hours", type=float, default=HISTORY_FIT_HOURS,
                   help="with several days: hours of windows picked across them to fit "
                        f"(default {HISTORY_FIT_HOURS:g}); the rest of every day validates")
    p.add_argument("--force", action="store_true",
                   help="deploy the calibrated parameters even when they predict the "
                        "validation data worse than the current ones (default: keep the "
                        "current ones, with the model error learned at them)")
    p.add_argument("--seed", type=int, default=0, help="TPE seed (default 0)")
    p.add_argument("--storage", default=None, metavar="URL",
                   help="Optuna storage shared by workers: journal:PATH, a .log file, "
                        "sqlite:///f.db, postgresql://... (default: a fresh journal file "
                        "beside --out, PARAMS.toml.optuna.log, for optuna-dashboard)")
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
    p.add_argument("--structure", action=argparse.BooleanOptionalAction, default=None,
                   help="search the model's structural alternatives on the history and adopt "
                        "one where the held-out evidence says so (default: on with several "
                        "days, off with one)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write an HTML page with the figures to DIR")
    p.add_argument("--json", default=None, metavar="FILE",
                   help="write the JSON summary here ('-': stdout)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_objective_arguments(p)
    _add_data_arguments(p)


def _fresh_journal(out: Path) -> str:
    """Without ``--storage``, the study goes to a journal file beside ``--out``
    (``PARAMS.toml.optuna.log``), started afresh, so that optuna-dashboard can open what the
    calibration did (an in-memory study left nothing to look at)."""
    journal = out.with_name(out.name + ".optuna.log")
    for stale in (journal, journal.with_name(journal.name + ".lock")):
        stale.unlink(missing_ok=True)
    return str(journal)


def calibrate_main(args: argparse.Namespace) -> int:
    """``softsensor calibrate``: fit on the history, validate, learn the model error, write
    PARAMS.toml (always: the calibrated parameters, or the current ones kept when the
    calibrated ones validate worse), print a JSON summary."""
    require_packages("calibrate", "optuna", "matplotlib")
    import optuna

    from softsensor.calibration.history_calibration import calibrate_history

    base, current = load_config_and_params(args)
    calibration = _calibration_settings(args, base)
    out = Path(args.out)
    check_target(out, "--out")
    check_target(args.json)
    if not args.fit_hours > 0:
        raise ConfigError(f"--fit-hours must be > 0, got {args.fit_hours}")
    selection = _selection(args)
    settings = _study_settings(args, out)
    optuna.logging.set_verbosity(optuna.logging.WARNING)  # the progress bar says enough
    days, regression, no_regression = _history(args.days, base)
    validation = [load_segment(p, base) for p in args.validate_on] if args.validate_on else None

    def progress(phase: str) -> None:
        if not args.quiet:
            print(f"calibrate: {phase} ...", file=sys.stderr, flush=True)

    hist = calibrate_history(days, base, settings, calibration,
                             current_theta=current.parameter_vector(),
                             window_hours=selection.window_hours, fit_hours=args.fit_hours,
                             min_labs=selection.min_labs,
                             windows_per_day=selection.windows_per_day,
                             polish=not args.no_polish,
                             identify_result=not args.no_identify, force=args.force,
                             validation=validation, progress=progress,
                             structure=default_structure(base, len(args.days), args.structure))
    for c in hist.calibration.choices:
        print(f"calibrate: {c.reason}", file=sys.stderr)
    doc = _params_doc(base, hist)
    if regression is not None:
        doc["regression"] = regression.to_table()
    write_params(out, doc, _params_comment(calibration, hist))
    outcome = calibration_outcome(hist, out, display_settings(base).moisture_basis)
    write_json(_calibrate_summary(args, out, hist, outcome), args.json)
    _say_outcome(hist, outcome, no_regression)
    return 0


def _study_settings(args: argparse.Namespace, out: Path) -> Any:
    """The Optuna study of ``calibrate`` (checked): in a fresh journal beside ``out`` unless
    ``--storage`` says where."""
    from softsensor.calibration.optimize import StudySettings

    settings = StudySettings(n_trials=args.trials, seed=args.seed,
                             storage=args.storage or _fresh_journal(out),
                             study_name=args.study_name, n_chunks=args.chunks,
                             batch=args.batch, prune=not args.no_prune,
                             progress=not args.quiet and sys.stderr is not None)
    settings.check()
    return settings


def _history(paths: Sequence[str | Path], base: PlantConfig
             ) -> tuple[list[Segment], Any, str | None]:
    """The history's days as model windows and the lab regression fitted on them (or None
    and why not, :func:`~softsensor.calibration.history_calibration.history_regression`):
    each day read once, for both."""
    from softsensor.calibration.history_calibration import history_regression

    days, rows = [], []
    for p in paths:
        day = read_day_inputs(p)
        days.append(segment_from_day(day, base, source=str(p)))
        rows.append(day)
    regression, no_regression = history_regression(rows)
    return days, regression, no_regression


def _calibrate_summary(args: argparse.Namespace, out: Path, hist: Any, outcome: str
                       ) -> dict[str, Any]:
    """The JSON ``calibrate`` prints: where PARAMS.toml went, the outcome, the calibration's
    and the history's summaries, and the report page when ``--report`` asked for one."""
    result = hist.calibration
    summary = {"out": str(out), "outcome": outcome, **result.summary(),
               "history": hist.summary()}
    if args.report:
        from softsensor.presentation.calibration_report import calibration_page

        summary["report"] = str(calibration_page(result, args.report, verdict=outcome,
                                                 structure=hist.structure, params_path=out))
    return summary


def _say_outcome(hist: Any, outcome: str, no_regression: str | None) -> None:
    """The closing lines on stderr: why no regression was written (said after the
    calibration, which may refuse the days first), the trade-off, the structure, the
    outcome."""
    result = hist.calibration
    if no_regression:
        print(f"calibrate: no [regression] written: {no_regression}", file=sys.stderr)
    if result.trade_off is not None:
        print(f"calibrate: {result.trade_off.verdict()}", file=sys.stderr)
    if hist.structure is not None:
        print(f"calibrate: {hist.structure.line()}", file=sys.stderr)
    print(f"calibrate: {outcome}", file=sys.stderr)


def _errors(new: dict[str, float], old: dict[str, float], x_ref: float, basis: str) -> str:
    """RMSEs before and after in plant units (°C, % points on ``basis`` at ``x_ref``)."""
    def pts(v: float) -> float:
        return moisture_pct_points(v, x_ref, basis)

    return (f"RMSE current -> calibrated: dryer outlet {old['T_dryer_out']:.2f} -> "
            f"{new['T_dryer_out']:.2f} °C, cyclone outlet {old['T_cyclone_out']:.2f} -> "
            f"{new['T_cyclone_out']:.2f} °C, outlet moisture {pts(old['moisture_out']):.2f} -> "
            f"{pts(new['moisture_out']):.2f} % points ({basis} basis)")


def calibration_outcome(hist: Any, out: Path, basis: str) -> str:
    """What ``calibrate`` wrote and why, for a person: the file to deploy, which parameters
    it holds and the errors before and after, in plant units. The terminal's last line and
    the report page's verdict say this same text."""
    from softsensor.presentation.calibration_report import lab_reference

    result, n = hist.calibration, hist.model_error.days
    new, old, where = result.validation, result.current_validation, "held-out data"
    if new is None or old is None:
        new, old, where = result, result.current_evaluation, "calibration data"
    errors = ("" if old is None else
              _errors(new.fit.rmse, old.fit.rmse, lab_reference(result.segments), basis))
    learned = f"the model error learned from {n} day(s)"
    if hist.kept_current:
        return (f"Deploy {out}: it holds the current parameters, kept because the calibrated "
                f"ones predict the {where} worse ({errors}), and {learned}; --force writes the "
                f"calibrated ones instead.")
    flags = result.at_bounds
    bounds = (f" At a search bound (not pinned by the data): {', '.join(flags)}."
              if flags else "")
    if not result.accepted:
        return (f"Deploy {out} only if you trust it: it holds the calibrated parameters, "
                f"written because --force asked though they predict the {where} worse than "
                f"the current ones ({errors}), and {learned}.{bounds}")
    worse = ("" if old is None or not new.fit.rmse["moisture_out"]
             > old.fit.rmse["moisture_out"] else
             " Worse on the outlet moisture than the parameters it replaces: accepted on the "
             "weighted cost of all three channels, not on the moisture.")
    return (f"Deploy {out}: it holds the calibrated parameters and {learned}. Errors on the "
            f"{where}: {errors}.{worse}{bounds}" if errors else
            f"Deploy {out}: it holds the calibrated parameters and {learned}.{bounds}")


def _params_doc(base: PlantConfig, hist: Any) -> dict[str, Any]:
    """PARAMS.toml of a calibration from history: the deployed parameters, the study's fit
    with whether they were kept, the discrepancy and the model error."""
    result = hist.calibration
    verdicts = None
    if result.identifiability is not None and not hist.kept_current:
        verdicts = {v.name: v.verdict for v in result.identifiability.verdicts}
    fit = {**result.fit_section(), "deployed": "current" if hist.kept_current else "calibrated",
           "deployed_reason": hist.reason,
           "calibrated_values": result.params,
           "inlet_levels": hist.inlet_levels}
    at = [] if hist.kept_current else result.at_bounds
    adopted = None if hist.structure is None else hist.structure.adopted
    deployed = base if adopted is None else base.with_keys(adopted.keys)
    return params_document(deployed, hist.params, fit, verdicts, at,
                           None if hist.discrepancy is None else hist.discrepancy.as_table(),
                           hist.model_error.to_table(),
                           None if hist.structure is None else hist.structure.params_table())


def _params_comment(calibration: CalibrationSettings, hist: Any) -> str:
    which = ("the current parameters, kept: the calibrated ones validated worse"
             if hist.kept_current else "calibrated")
    return (f"Written by `softsensor calibrate` ({which}; cost {calibration.cost}, inlet "
            f"moisture {calibration.inlet}, prior "
            f"{calibration.prior_sigma if calibration.prior else 'none'}; Table 1 bounds;\n"
            f"model error learned from {hist.model_error.days} day(s) of history).\n"
            f"Load with softsensor.plantconfig.load_parameters or --params.")


# ---------------------------------------------------------------------------- identify
def add_identify_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap", help="recorded day(s)")
    p.add_argument("--params", default=None, metavar="PARAMS.toml",
                   help="parameters to analyse at (default: the config's values)")
    p.add_argument("--storage", default=None, metavar="URL",
                   help="the calibration study, for parameter importance (Fig. 4)")
    p.add_argument("--study-name", default=DEFAULT_STUDY_NAME,
                   help=f"study in --storage (default {DEFAULT_STUDY_NAME})")
    p.add_argument("--importance", default="ped-anova", choices=("ped-anova", "fanova"),
                   help="importance evaluator (fanova, the paper's, needs scikit-learn)")
    p.add_argument("--json", default=None, metavar="FILE",
                   help="write the full analysis here ('-': stdout)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write an HTML page with the figures to DIR")
    _add_objective_arguments(p)
    _add_data_arguments(p)


def identify_main(args: argparse.Namespace) -> int:
    """``softsensor identify``: sensitivities, FIM, correlations, verdicts."""
    require_packages("identify", "optuna", "matplotlib")
    from softsensor.calibration.calibration_run import objective_spec
    from softsensor.calibration.identifiability import identify
    from softsensor.model import DryerModel
    from softsensor.presentation.calibration_report import identifiability_table, identify_page

    check_target(args.json)
    base, config = load_config_and_params(args)
    calibration = _calibration_settings(args, base)
    segments, choices = load_segments(args.days, config, _selection(args))
    model = DryerModel(config)
    theta = config.parameter_vector()
    spec = objective_spec(model, segments, base, calibration)
    ident, sens = identify(model, segments, theta, spec, config.bounds())
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
    print(f"\nweighted FIM (Table 3 form) condition number {ident.condition_number:.3g} "
          f"(the paper's: {PAPER_CONDITION_NUMBER:.0f}); identifiable: "
          f"{', '.join(ident.identifiable) or 'none'}; "
          f"poorly identifiable: {', '.join(ident.poorly_identifiable) or 'none'}")
    doc = {
        "windows": [c.reason for c in choices],
        "params": dict(zip(PARAMETER_NAMES, map(float, theta), strict=True)),
        "cost_kind": spec.cost, "inlet": calibration.inlet,
        "verdicts": {v.name: {"verdict": v.verdict, "relative_se": v.relative_se,
                              "posterior_over_prior": v.prior_ratio,
                              "most_correlated": v.partner, "correlation": v.correlation,
                              "profile_rise": v.rise,
                              "reason": v.reason} for v in ident.verdicts},
        "fim": ident.fim.tolist(), "fim_condition_number": ident.condition_number,
        "paper_condition_number": PAPER_CONDITION_NUMBER,
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
                                          importance, cost=spec.cost, segments=segments))
    write_json(doc, args.json)
    return 0


# ---------------------------------------------------------------------------- validate
def add_validate_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("days", nargs="+", metavar="DAY.mcap", help="independent recorded day(s)")
    p.add_argument("--params", required=True, metavar="PARAMS.toml",
                   help="calibrated parameters")
    p.add_argument("--json", default=None, metavar="FILE",
                   help="write the JSON summary here ('-': stdout)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write Fig. 6 and an HTML page to DIR")
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    _add_objective_arguments(p)


def validate_main(args: argparse.Namespace) -> int:
    """``softsensor validate``: per-channel RMSE and eq. 4 cost on other days of
    ``--params`` in the sensor's mode (the inlet read from the temperatures) with its verdict
    against the plant's history days, open loop beside it, then the config's defaults."""
    require_packages("validate", "optuna", "matplotlib")
    from softsensor.calibration.open_loop_errors import displayed
    from softsensor.diagnosis.plant_normal import history_checks

    check_target(args.json)
    base, config = load_config_and_params(args)
    fit = read_fit(args.params)
    calibration = _calibration_settings(args, base)
    if args.cost is None and isinstance(fit.get("cost_kind"), str) \
            and fit["cost_kind"] in COSTS and not args.paper:
        calibration = dataclasses.replace(calibration, cost=fit["cost_kind"])
    raw = [load_segment(p, config) for p in args.days]
    runs = _validation_runs(base, config, fit, calibration, raw)
    history = history_checks(args.params, runs["params"][1].fit.rmse, runs["params"][0]["rmse"])
    text = _validation_text(runs, raw, base, history["sensor"])
    doc = {**_validation_doc(args, raw, runs, text), "history": history}
    if args.report:
        from softsensor.presentation.calibration_report import validation_page

        (open_loop, result), (_, default) = runs["params"], runs["default"]
        shown = dataclasses.replace(result, segments=raw, runs=[
            displayed(config, s, r) for s, r in zip(raw, result.runs, strict=True)])
        doc["report"] = str(validation_page(shown, config, args.report, open_loop,
                                            default=default, verdict=text))
    write_json(doc, args.json)
    print(f"validate: {len(raw)} day(s): {text}", file=sys.stderr)
    return 0


def _validation_runs(base: PlantConfig, config: PlantConfig, fit: dict[str, Any],
                     calibration: CalibrationSettings, raw: Sequence[Segment]
                     ) -> dict[str, tuple[Any, Any]]:
    """``{"params": ..., "default": ...}``: for the parameters of ``--params`` (``config``,
    its ``[fit]`` section ``fit``) and for the config's defaults, the open-loop summary and
    the validation with the inlet moisture read from the temperatures, scored with the
    objective of ``calibration``."""
    from softsensor.calibration.calibration_run import objective_spec
    from softsensor.calibration.open_loop_errors import open_loop_summary, prepared
    from softsensor.calibration.validation import validate_many
    from softsensor.model import DryerModel

    model = DryerModel(config)
    # the calibration cost of the parameters the file holds: the current ones when it kept them
    cal_cost = fit.get("cost_at_current" if fit.get("deployed") == "current" else "cost")
    cal_cost = float(cal_cost) if isinstance(cal_cost, (int, float)) else None
    runs, spec = {}, None
    for name, cfg, cost in (("params", config, cal_cost), ("default", base, None)):
        segs = [prepared(cfg, s) for s in raw]
        spec = spec or objective_spec(model, segs, base, calibration)
        read = validate_many(segs, cfg, spec, [cfg.parameter_vector()], [cost], model)[0]
        runs[name] = (open_loop_summary(cfg, raw, fit if cfg is config else None, model), read)
    return runs


def _validation_text(runs: dict[str, tuple[Any, Any]], raw: Sequence[Segment],
                     base: PlantConfig, history: dict[str, Any]) -> str:
    """The verdict line of ``validate`` (:func:`~softsensor.presentation.verdicts.
    validation_verdict`, the sensor's mode against ``history``), the defaults beside."""
    from softsensor.presentation.calibration_report import lab_reference
    from softsensor.presentation.verdicts import validation_verdict

    (open_loop, result), (d_open, default) = runs["params"], runs["default"]
    x_ref, basis = lab_reference(raw), display_settings(base).moisture_basis
    text = validation_verdict(open_loop, result.fit.rmse, x_ref, basis, history)
    if np.array_equal(result.theta, default.theta) and open_loop["rmse"] == d_open["rmse"]:
        return text + " They are the config's default parameters."
    pts = moisture_pct_points(d_open["rmse"]["moisture_out"], x_ref, basis)
    d = d_open["rmse"]
    return text + (f" With the config's default parameters instead (open loop): dryer outlet "
                   f"{d['T_dryer_out']:.2f} °C, cyclone outlet {d['T_cyclone_out']:.2f} °C "
                   f"and outlet moisture {pts:.2f} % points.")


def _validation_doc(args: argparse.Namespace, raw: Sequence[Segment],
                    runs: dict[str, tuple[Any, Any]], text: str) -> dict[str, Any]:
    """``validate``'s JSON: open loop, the inlet read, the verdict, the defaults beside."""
    (open_loop, result), (d_open, default) = runs["params"], runs["default"]
    read = result.inlet_read()
    read["moisture_worse_than_open_loop"] = bool(
        read["rmse"]["moisture_out"] > open_loop["rmse"]["moisture_out"])
    return {"days": [str(p) for p in args.days], "hours": float(sum(s.hours for s in raw)),
            "headline": "inlet_read", "open_loop": open_loop, "inlet_read": read,
            "summary": text,
            "default_parameters": {
                "open_loop": {k: d_open[k] for k in ("rmse", "weighted_rmse", "cost",
                                                     "inlet_moisture")},
                "inlet_read": {k: v for k, v in default.inlet_read().items()
                               if k in ("rmse", "weighted_rmse", "cost", "score")}}}


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``calibrate``, ``identify`` and ``validate`` on the ``softsensor`` parser."""
    p = sub.add_parser("calibrate", help="fit the seven Table 1 parameters to recorded days")
    add_calibrate_arguments(p)
    p.set_defaults(func=calibrate_main)
    p = sub.add_parser("identify", help="which parameters the data can pin down (FIM)")
    add_identify_arguments(p)
    p.set_defaults(func=identify_main)
    p = sub.add_parser("validate", help="RMSE and eq. 4 cost of PARAMS.toml on other days")
    add_validate_arguments(p)
    p.set_defaults(func=validate_main)


__all__ = ["add_calibrate_arguments", "add_commands", "add_identify_arguments",
           "add_validate_arguments", "calibrate_main", "identify_main", "validate_main"]
