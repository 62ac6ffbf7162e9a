"""Calibration report pages: the figures of :mod:`.calibration_figures` plus the tables, as
Markdown in one folder.

``calibrate --report DIR`` writes the calibration page (Figs. 2 to 5, parameters, fit, the
chosen window and why, the identifiability table and the weighted FIM of the paper's
Table 3 form); ``identify --report DIR`` the identifiability page; ``validate --report DIR``
the validation page (Fig. 6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from softsensor.calibration.calibration_run import CalibrationResult
from softsensor.calibration.cost import Fit, weighted_rmse
from softsensor.calibration.identifiability import (
    PAPER_CONDITION_NUMBER,
    Identifiability,
    Sensitivities,
)
from softsensor.calibration.settings import calibration_settings
from softsensor.calibration.structure_search import StructureSearch
from softsensor.calibration.trade_off import FrontPoint, TradeOff
from softsensor.calibration.validation import ValidationResult
from softsensor.configfile import read_toml
from softsensor.errors import ConfigError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig, dotted_keys
from softsensor.presentation import calibration_figures as figures
from softsensor.presentation.deployed_model import PAPER_FORM, DeployedModel
from softsensor.presentation.display import (
    DisplaySettings,
    display_settings,
    lab_reference,
    plant_error,
)
from softsensor.presentation.verdicts import calibration_result_verdict, validation_verdict
from softsensor.signals import OUTPUT_NAMES


def _dir(path: str | Path) -> Path:
    d = Path(path)
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--report {d}: cannot create: {exc.strerror}") from exc
    return d


def fit_table(fit: Fit, weights: np.ndarray, display: DisplaySettings, x_ref: float) -> str:
    """Errors per channel in plant units (°C, % points on the display basis at ``x_ref``),
    as the verdict above them says them; the weighted terms of eq. 4 beside."""
    w = weighted_rmse(fit, weights)
    rows = []
    for n in OUTPUT_NAMES:
        value, unit = plant_error(n, fit.rmse[n], x_ref, display)
        rows.append((n, unit, fit.n[n], f"{value:.3g}", f"{w[n]:.4g}"))
    rows.append(("**cost J (eq. 4)**", "", "", "", f"**{fit.cost:.4g}**"))
    return figures.markdown_table(("channel", "unit", "samples", "RMSE", "WF x RMSE (SI)"),
                                  rows)


def trade_off_table(trade: TradeOff, display: DisplaySettings, x_ref: float) -> str:
    """The multipliers' front on the held-out data, in plant units, under its verdict: per
    point both temperatures and the lab moisture, the inlet read from the temperatures and
    open loop (:mod:`softsensor.calibration.trade_off`)."""
    def cells(rmse: dict[str, float] | None) -> tuple[str, ...]:
        if rmse is None:
            return ("", "", "")
        return tuple(f"{plant_error(n, rmse[n], x_ref, display)[0]:.3g}"
                     for n in OUTPUT_NAMES)

    unit = plant_error("moisture_out", 0.0, x_ref, display)[1]
    rows = [(p.label, *cells(p.fit), *cells(p.held_out), *cells(p.open_loop))
            for p in trade.points]
    head = ("point", "fit T_dryer_out °C", "fit T_cyclone_out °C", f"fit lab {unit}",
            "held-out T_dryer_out", "held-out T_cyclone_out", f"held-out lab {unit}",
            "open loop T_dryer_out", "open loop T_cyclone_out", f"open loop lab {unit}")
    return (f"{trade.verdict()[0].upper()}{trade.verdict()[1:]}.\n\n"
            + figures.markdown_table(head, rows)
            + "\n\nFit: the study's view (inlet trajectory fitted to temperatures and labs). "
              "Held out: the inlet moisture read from the temperatures, the labs out of "
              "sample (what the sensor does). Open loop: the nominal inlet moisture.")


def identifiability_table(ident: Identifiability, config: PlantConfig,
                          importance: dict[str, float] | None = None) -> str:
    """Which parameters the data can and cannot pin down."""
    rows = []
    for v in ident.verdicts:
        spec = config.parameters[v.name]
        imp = "" if importance is None else f"{importance.get(v.name, 0.0):.3f}"
        rise = "" if np.isnan(v.rise) else f"{min(v.rise, 999):.3g}"
        rows.append((v.name, f"{v.value:.5g}", f"[{spec.low:g}, {spec.high:g}]",
                     f"{100 * v.relative_se:.3g} %", rise, f"{v.prior_ratio:.2f}",
                     f"{v.partner} ({v.correlation:+.2f})", imp, f"**{v.verdict}**",
                     v.reason))
    return figures.markdown_table(
        ("parameter", "value", "bounds", "FIM s.e.", "rise at ±15 %",
         "post./prior sd", "most correlated", "importance", "verdict", "why"), rows)


def matrix_table(M: np.ndarray, fmt: str = "{:.3g}") -> str:
    rows = [(PARAMETER_NAMES[i], *(fmt.format(x) for x in M[i])) for i in range(len(M))]
    return figures.markdown_table(("", *PARAMETER_NAMES), rows)


def noise_line(noise: np.ndarray, display: DisplaySettings, x_ref: float) -> str:
    """The channels' noise as the page's tables say errors: °C and % points on the display
    basis at ``x_ref`` (issue 40: this line alone said K and kg/kg)."""
    parts = []
    for n, sd in zip(OUTPUT_NAMES, noise, strict=True):
        value, unit = plant_error(n, float(sd), x_ref, display)
        parts.append(f"{n} {value:.3g} {unit}")
    return ", ".join(parts)


def identifiability_sections(ident: Identifiability, config: PlantConfig,
                             importance: dict[str, float] | None,
                             x_ref: float = 0.1) -> list[tuple[str, str]]:
    weak = "\n".join(f"- {d}" for d in ident.weakest_directions(2))
    noise = noise_line(ident.noise, display_settings(config), x_ref)
    return [
        ("What the data can and cannot pin down",
         identifiability_table(ident, config, importance)
         + f"\n\n'FIM s.e.': local relative standard error from the statistical FIM with "
           f"channel noise {noise} (the fit's RMSE, inflated for serial correlation) and the "
           "calibration's prior; 'post./prior sd' near 1 means the data add nothing. 'rise "
           "at ±15 %': how much the objective rises (in units of the prior's scale) when the "
           "parameter moves 15 % with the others re-fitted (worse side); identifiable needs "
           "a s.e. of at most 7.5 % and a rise of at least 2."),
        ("Weighted Fisher information (paper's Table 3 form, ln θ)",
         matrix_table(ident.fim)
         + f"\n\nCondition number {ident.condition_number:.3g} (the paper's Table 3: "
           f"{PAPER_CONDITION_NUMBER:.0f}). "
           "Least informed directions:\n" + weak),
        ("Parameter correlation matrix", matrix_table(ident.correlation, "{:+.2f}")),
    ]


def structure_table(search: StructureSearch, display: DisplaySettings, x_ref: float) -> str:
    """The structural alternatives tried on the history: what each changes, its held-out
    errors in plant units, its evidence gain, adopted or why not."""
    def cells(rmse: dict[str, float]) -> tuple[str, ...]:
        return tuple(f"{plant_error(n, rmse[n], x_ref, display)[0]:.3g}" for n in OUTPUT_NAMES)

    unit = plant_error("moisture_out", 0.0, x_ref, display)[1]
    rows = [("paper's form (baseline)", "", *cells(search.baseline_held_out), "0", "")]
    for c in search.candidates:
        a = c.candidate
        changes = ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                            for k, v in c.keys.items() if not k.startswith("parameters."))
        rows.append((a.name, f"{changes} ({a.source})", *cells(c.held_out), f"{c.gain:.1f}",
                     "**adopted**" if c.adopted else c.why_not))
    return (search.line() + "\n\n" + figures.markdown_table(
        ("alternative", "keys (source)", "held-out T_dryer_out °C", "held-out T_cyclone_out °C",
         f"held-out lab {unit}", "evidence gain", "adopted or why not"), rows))


def deployed_table(params_path: str | Path) -> str:
    """What the written PARAMS.toml deploys, read back from the file: every parameter's value
    and bounds, and every ``[structure]`` key (issue 40: the page showed the study's values
    while the file deployed others, one below the bounds printed beside it)."""
    doc = read_toml(params_path)
    rows = [(name, f"{float(spec['value']):.5g}", f"[{float(spec['low']):g}, "
             f"{float(spec['high']):g}]", str(spec.get("verdict", "")),
             "yes" if spec.get("at_bound") else "")
            for name, spec in doc.get("parameters", {}).items()]
    text = (f"`{params_path}`, as written:\n\n"
            + figures.markdown_table(("parameter", "deployed", "bounds", "verdict",
                                      "at a bound"), rows))
    structure = dotted_keys(doc.get("structure", {}))  # the keys load_parameters applies
    if structure:
        keys = [(key, f"{value:.5g}" if isinstance(value, float) else str(value))
                for key, value in structure.items()]
        text += ("\n\nIts `[structure]`, which replaces these keys of the plant config:\n\n"
                 + figures.markdown_table(("key", "deployed"), keys))
    fit = doc.get("fit", {})
    if fit.get("deployed"):
        why = f" ({fit['deployed_reason']})" if fit.get("deployed_reason") else ""
        text += f"\n\nDeployed: the {fit['deployed']} parameters{why}."
    return text


def deployed_errors_table(params_path: str | Path, display: DisplaySettings, x_ref: float
                          ) -> str:
    """The deployed model's own errors, read back from PARAMS.toml's ``[fit.deployed_model]``
    (:meth:`~softsensor.presentation.deployed_model.DeployedModel.fit_table`), beside the
    current parameters' on the same data, in plant units (issue 49: the page gave the study's
    paper-form errors while the file deployed another structure)."""
    dep = read_toml(params_path).get("fit", {}).get("deployed_model", {})
    rmse, cur, ol = dep.get("rmse"), dep.get("current_rmse"), dep.get("open_loop_rmse")
    if not rmse:
        return "The file holds no errors of the deployed model."

    def cell(table: dict[str, float] | None, n: str) -> str:
        return "" if not table else f"{plant_error(n, float(table[n]), x_ref, display)[0]:.3g}"

    rows = [(n, plant_error(n, 0.0, x_ref, display)[1], cell(cur, n), cell(rmse, n),
             cell(ol, n)) for n in OUTPUT_NAMES]
    return (f"The model `{params_path}` deploys ({dep.get('structure')}, "
            f"{dep.get('parameters')} parameters) on the {dep.get('where')}, from its "
            f"`[fit.deployed_model]`:\n\n"
            + figures.markdown_table(("channel", "unit", "current parameters, RMSE",
                                      "deployed, RMSE", "deployed, open loop"), rows)
            + "\n\nRMSE: the inlet moisture read from the temperatures, the labs out of "
              "sample (what the sensor does); open loop: the inlet moisture held at the "
              "nominal level.")


def deployed_front(trade: TradeOff, params_path: str | Path) -> TradeOff:
    """The front as PARAMS.toml deploys it: when the file deploys the study's parameters in
    the paper's form, ``trade`` as it is; otherwise the study's point renamed and the star
    ("deployed") on the model the file deploys, the current parameters kept or an adopted
    structure's own held-out errors (``[fit.deployed_model]``)."""
    doc = read_toml(params_path)
    dep = doc.get("fit", {}).get("deployed_model", {})
    structure, which = dep.get("structure", PAPER_FORM), dep.get("parameters", "calibrated")
    if structure == PAPER_FORM and which == "calibrated":
        return trade
    points = []
    for p in trade.points:
        if p.label == "deployed":
            p = dataclasses.replace(p, label="study (paper's form)")
        elif p.label == "current" and structure == PAPER_FORM:
            p = dataclasses.replace(p, label="deployed")  # the current parameters, kept
        points.append(p)
    if structure != PAPER_FORM and dep.get("rmse"):
        theta = np.array([float(doc["parameters"][n]["value"]) for n in PARAMETER_NAMES])
        points.append(FrontPoint("deployed", theta, None,  # type: ignore[arg-type]
                                 {n: float(dep["rmse"][n]) for n in OUTPUT_NAMES},
                                 None if not dep.get("open_loop_rmse") else
                                 {n: float(dep["open_loop_rmse"][n]) for n in OUTPUT_NAMES}))
    return dataclasses.replace(trade, points=points)


def calibration_page(result: CalibrationResult, directory: str | Path,
                     verdict: str | None = None,
                     structure: StructureSearch | None = None,
                     params_path: str | Path | None = None,
                     deployed: DeployedModel | None = None) -> Path:
    """Figures and tables of a calibration (Figs. 2 to 5) under ``verdict`` (default: the
    shared calibration verdict of :mod:`softsensor.presentation.verdicts`); with
    ``params_path``, first what that PARAMS.toml deploys (:func:`deployed_table`) and the
    deployed model's own errors (:func:`deployed_errors_table`), the front's star on it
    (:func:`deployed_front`), and the study's own values named as such; with ``deployed``
    (the model the file deploys, :func:`~softsensor.presentation.deployed_model.
    deployed_model`), its identifiability, trajectories and profiles rather than the
    study's."""
    d = _dir(directory)
    cfg = result.config
    shown = deployed.config if deployed is not None else cfg
    theta = deployed.theta if deployed is not None else result.theta
    other = deployed is not None and (deployed.structure != PAPER_FORM
                                      or deployed.parameters != "calibrated")
    model = DryerModel(shown)
    sections: list[tuple[str, str]] = []
    disp, x_ref = display_settings(cfg), lab_reference(result.segments)
    if params_path is not None:
        sections.append(("Deployed parameters (PARAMS.toml)", deployed_table(params_path)))
        sections.append(("Errors of the deployed model (PARAMS.toml)",
                         deployed_errors_table(params_path, disp, x_ref)))
    rows = [(n, f"{result.theta[i]:.5g}", f"{cfg.parameters[n].value:.5g}",
             f"[{cfg.parameters[n].low:g}, {cfg.parameters[n].high:g}]")
            for i, n in enumerate(PARAMETER_NAMES)]
    sections.append(("The study's fit (paper's form, before the deploy decision and the "
                     "structure search)" if params_path is not None else "Calibrated parameters",
                     figures.markdown_table(("parameter", "study's fit", "config", "bounds"),
                                            rows)))
    cur = result.current_evaluation
    sections.append(("The study's fit on the calibration data (paper's form)" if other else
                     "Fit on the calibration data",
                     fit_table(result.fit, cfg.cost.weights(), disp, x_ref)
                     + "\n\nEq. 4 at the current parameters: "
                     + ("n/a" if cur is None else f"{cur.fit.cost:.4g}")
                     + f"\n\n{'The study: ' if other else ''}{result.verdict_line()}"))
    if result.trade_off is not None:
        trade = (result.trade_off if params_path is None
                 else deployed_front(result.trade_off, params_path))
        figures.front_figure(trade, disp, x_ref, d / "front.png")
        sections.append(("Temperatures against moisture: the multipliers' front",
                         "![](front.png)\n\n" + trade_off_table(trade, disp, x_ref)))
    if structure is not None:
        sections.append(("The model's structure, chosen by evidence from history",
                         structure_table(structure, disp, x_ref)))
    sections.append(("Calibration window", "\n".join(f"- {c.reason}" for c in result.choices)
                     or "- " + ", ".join(s.source for s in result.segments)))
    runs = deployed.runs if deployed is not None and deployed.runs is not None else result.runs
    figures.trajectory_figure(result.segments, runs, d / "fig5_calibration.png",
                              "Calibration: the deployed model vs measurements" if other else
                              "Calibration: model at the calibrated parameters vs measurements",
                              display_settings(cfg))
    sections.append(("Calibration trajectories (Fig. 5)", "![](fig5_calibration.png)"))
    figures.study_figure(result.study, result.importance or {}, d / "fig4_study.png",
                         result.spec.cost)
    sections.append(("Objective by trial and parameter importance (Fig. 4)",
                     "![](fig4_study.png)\n\nTPE best: trial "
                     f"{result.tpe_best['trial']} (objective "
                     f"{result.tpe_best['objective']:.4g}); after the local polish: "
                     f"{result.evaluation.objective:.4g}."))
    ident, sens = result.identifiability, result.sensitivities
    if deployed is not None:
        ident, sens = deployed.identifiability, deployed.sensitivities
    if ident is not None and sens:
        figures.sensitivity_figure(sens[0], d / "fig2_sensitivity.png")
        sections.append(("Sensitivity trajectories (Fig. 2)", "![](fig2_sensitivity.png)"))
        sections += identifiability_sections(ident, shown, None if other else result.importance,
                                             x_ref)
    elif other:
        sections.append(("What the data can and cannot pin down",
                         "Not analysed for the deployed model (`--no-identify`)."))
    u = np.median(result.segments[0].U, axis=0)
    figures.profile_step_figure(model, theta, u, d / "fig3_profile_steps.png")
    sections.append(("Axial profile response to steps in T_air_in (Fig. 3)",
                     "![](fig3_profile_steps.png)"))
    verdict = verdict or calibration_result_verdict(result, display_settings(cfg).moisture_basis)
    return figures.write_page(d, "Calibration report", sections, verdict=verdict)


def identify_page(ident: Identifiability, sens: Sensitivities, config: PlantConfig,
                  theta: np.ndarray, directory: str | Path, study=None,
                  importance: dict[str, float] | None = None, *, cost: str | None = None,
                  segments=None) -> Path:
    """The identifiability report; ``cost`` names the objective the study minimised (None:
    the config's ``[calibration] cost``), ``segments`` give the lab moisture at which kg/kg
    errors become % points (:func:`lab_reference`; None: ``sens``'s segment), as on the
    calibration page."""
    d = _dir(directory)
    model = DryerModel(config)
    cost = calibration_settings(config).cost if cost is None else cost
    x_ref = lab_reference([sens.segment] if segments is None else segments)
    figures.sensitivity_figure(sens, d / "fig2_sensitivity.png")
    sections = [("Sensitivity trajectories (Fig. 2)", "![](fig2_sensitivity.png)")]
    sections += identifiability_sections(ident, config, importance, x_ref)
    if study is not None:
        figures.study_figure(study, importance or {}, d / "fig4_study.png", cost)
        sections.append(("Objective by trial and parameter importance (Fig. 4)",
                         "![](fig4_study.png)"))
    u = np.median(sens.segment.U, axis=0)
    figures.profile_step_figure(model, theta, u, d / "fig3_profile_steps.png")
    sections.append(("Axial profile response to steps in T_air_in (Fig. 3)",
                     "![](fig3_profile_steps.png)"))
    return figures.write_page(d, "Identifiability report", sections,
                              verdict=identifiability_verdict(ident))


def validation_page(result: ValidationResult, config: PlantConfig, directory: str | Path,
                    open_loop: Mapping[str, Any], default: ValidationResult | None = None,
                    verdict: str | None = None) -> Path:
    """Fig. 6 and the validation's tables: open loop first (``open_loop``, :func:`~softsensor.
    calibration.open_loop_errors.open_loop_summary`) with the calibration's held-out error beside,
    then with the inlet moisture read from the temperatures (``result``); ``default``: the
    config's default parameters on the same data; ``verdict``: the sentence first on the page
    (:func:`~softsensor.presentation.verdicts.validation_verdict`, which the ``validate`` line says
    too)."""
    d = _dir(directory)
    disp, x_ref = display_settings(config), lab_reference(result.segments)
    figures.trajectory_figure(result.segments, result.runs, d / "fig6_validation.png",
                              "Validation: calibrated model vs independent data", disp)
    ratio = "n/a" if result.ratio is None else f"{result.ratio:.2f}"
    w = config.cost.weights()
    ol = Fit(dict(open_loop["rmse"]), dict(open_loop["samples"]), float(open_loop["cost"]))
    ref = open_loop.get("reference")
    held = ("The parameter file holds no held-out error of its calibration." if ref is None
            else f"The calibration's held-out error ({ref['source']}):\n\n"
            + fit_table(Fit(dict(ref["rmse"]), dict(open_loop["samples"]),
                            float(sum(wm * ref["rmse"][n]
                                      for wm, n in zip(w, OUTPUT_NAMES, strict=True)))),
                        w, disp, x_ref))
    normal = " and the history's normal" if open_loop.get("normal") else ""
    sections = [
        (f"Open loop (inlet moisture held at the calibration's "
         f"{open_loop['inlet_moisture']:.3f} kg/kg{normal})",
         fit_table(ol, w, disp, x_ref) + "\n\n" + held),
        ("Inlet moisture read from the temperatures",
         fit_table(result.fit, w, disp, x_ref)
         + f"\n\nValidation cost / calibration cost: {ratio}"),
    ]
    if default is not None:
        sections.append(("The config's default parameters on the same data (inlet moisture "
                         "read from the temperatures)", fit_table(default.fit, w, disp, x_ref)))
    sections.append(("Validation trajectories (Fig. 6)", "![](fig6_validation.png)"))
    title = ", ".join(s.source for s in result.segments)
    verdict = verdict or validation_verdict(open_loop, result.fit.rmse, x_ref,
                                            disp.moisture_basis)
    return figures.write_page(d, f"Validation report: {title}", sections, verdict=verdict)


def identifiability_verdict(ident: Identifiability) -> str:
    """Which parameters the data pin down, in one sentence."""
    good, poor = ident.identifiable, ident.poorly_identifiable
    text = (f"The data pin down {', '.join(good)}." if good
            else "The data pin down none of the seven parameters on their own.")
    if poor:
        text += (f" Not identifiable from these data: {', '.join(poor)} (their values come "
                 f"from the prior and the bounds; a designed experiment would help).")
    return text


__all__ = ["calibration_page", "deployed_errors_table", "deployed_front", "deployed_table",
           "fit_table", "identifiability_table",
           "identify_page", "lab_reference", "noise_line", "validation_page"]
