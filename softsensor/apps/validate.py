"""``softsensor validate``: how a calibration predicts days it did not see, argument parsing
and output only.

Open loop first (:mod:`softsensor.calibration.open_loop_errors`, the figure ``diagnose``
reports too) with its verdict against the calibration's own held-out error, then with the
inlet moisture read from the temperatures, labelled; beside them the config's default
parameters on the same data. It prints one JSON document (``--json``) and one line on
stderr; ``--report DIR`` writes the validation page
(:func:`softsensor.presentation.calibration_report.validation_page`). The options it shares
with ``calibrate`` (the objective, the data) and the reading of a day into model windows
are :mod:`softsensor.apps.calibrate`'s.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from softsensor.apps.calibrate import _add_objective_arguments, _calibration_settings, load_segment
from softsensor.apps.loading import load_config_and_params
from softsensor.apps.verb_output import write_json
from softsensor.calibration.dataset import Segment
from softsensor.calibration.params_file import read_fit
from softsensor.calibration.settings import COSTS, CalibrationSettings
from softsensor.errors import require_packages
from softsensor.files import check_target
from softsensor.plantconfig import PlantConfig
from softsensor.presentation.display import display_settings, moisture_pct_points


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
    validation_verdict`), with the config's default parameters beside unless they are the
    ones validated."""
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
    """The JSON ``validate`` prints: open loop first (the headline), the inlet read from the
    temperatures, the verdict, and the config's default parameters beside."""
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
    """Register ``validate`` on the ``softsensor`` parser."""
    p = sub.add_parser("validate", help="RMSE and eq. 4 cost of PARAMS.toml on other days")
    add_validate_arguments(p)
    p.set_defaults(func=validate_main)


__all__ = ["add_commands", "add_validate_arguments", "validate_main"]
