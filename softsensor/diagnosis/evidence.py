"""Evidence in words: what the residual statistics and the held-out scores say about a cause.

Each sentence quotes numbers an engineer can check against the report's plots: residual
means, trends and correlations (:mod:`.residuals`), the fitted extension
(:mod:`.extensions`) and its held-out RMSEs, cost and log-likelihood gain (:mod:`.verdict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softsensor.diagnosis.extensions import Fitted
from softsensor.diagnosis.residuals import ChannelStats, LabStats
from softsensor.diagnosis.shapes import ShapeFit
from softsensor.diagnosis.verdict import Score
from softsensor.signals import OUTPUT_NAMES


@dataclass(frozen=True)
class ResidualSummary:
    """Baseline residual statistics of a whole day, and the model's inlet-moisture signature.

    ``moisture_signature`` is the change of (``T_dryer_out`` [K], ``T_cyclone_out`` [K],
    ``moisture_out`` [kg/kg]) per +0.1 kg/kg of inlet moisture at the day's mean inputs.
    """

    channels: list[ChannelStats]
    lab: LabStats
    sigma: np.ndarray
    moisture_signature: np.ndarray
    ratio_cyc_dry: float
    corr_dry_cyc: float


def _fmt_unit(name: str, v: float) -> str:
    return f"{v:.4f} kg/kg" if name == "moisture_out" else f"{v:.2f} K"


def statistics_text(cause: str, s: ResidualSummary) -> str:
    """The residual statistics that bear on ``cause``."""
    d, c = s.channels
    lab = s.lab
    if cause == "inlet_moisture":
        sig = s.moisture_signature
        return (f"T_dryer_out and T_cyclone_out residuals correlate {s.corr_dry_cyc:+.2f} with "
                f"slope {s.ratio_cyc_dry:.2f} K/K (an inlet-moisture change moves them "
                f"{sig[0]:+.2f} K and {sig[1]:+.2f} K and moisture_out {sig[2]:+.4f} kg/kg per "
                f"+0.1 kg/kg); largest change of mean on T_dryer_out {d.change_shift:+.2f} K at "
                f"{d.change_hour:.1f} h (t = {d.change_t:.1f}); lab residual mean "
                f"{lab.mean:+.4f} kg/kg over {lab.n} results")
    if cause == "sensor_bias":
        sig = s.moisture_signature
        return (f"residual mean T_dryer_out {d.mean:+.2f} K (t = {d.t_mean:.1f}), "
                f"T_cyclone_out {c.mean:+.2f} K (t = {c.t_mean:.1f}) (a process change moves "
                f"both: an inlet-moisture change in the ratio {sig[1] / sig[0]:.2f}; an "
                f"offset moves one)")
    if cause == "lab_delay":
        return (f"lab RMSE {lab.rmse:.4f} kg/kg at the stamped sample times, "
                f"{lab.rmse_at_best_shift:.4f} with the times moved by "
                f"{lab.best_shift_min:+.0f} min; lab residuals correlate "
                f"{lab.corr_model_rate:+.2f} with the model's rate of change; temperature "
                f"residuals Ljung-Box p = {d.ljung_box_p:.2g} and {c.ljung_box_p:.2g}")
    if cause == "fouling_drift":
        return (f"residual trend T_dryer_out {d.slope_per_h:+.3f} K/h (t = {d.t_slope:.1f}), "
                f"T_cyclone_out {c.slope_per_h:+.3f} K/h (t = {c.t_slope:.1f}), lab "
                f"{lab.slope_per_h:+.5f} kg/kg/h")
    if cause == "input_lag":
        a, b = d.xcorr_rate["T_air_in"], c.xcorr_rate["T_air_in"]
        return (f"residuals correlate with the window-to-window change of T_air_in: "
                f"T_dryer_out {a.corr:+.2f} (lag {a.lag}), T_cyclone_out {b.corr:+.2f} "
                f"(lag {b.lag}); with T_air_in itself {d.xcorr['T_air_in'].corr:+.2f} and "
                f"{c.xcorr['T_air_in'].corr:+.2f}")
    if cause == "ambient_heat_loss":
        return (f"residual slope on T_amb: T_dryer_out {d.amb_slope:+.3f} K/K "
                f"(t = {d.t_amb_slope:.1f}), T_cyclone_out {c.amb_slope:+.3f} K/K "
                f"(t = {c.t_amb_slope:.1f}); correlation with H_amb {d.corr_H_amb:+.2f} and "
                f"{c.corr_H_amb:+.2f}")
    parts = [f"{ch.channel} RMSE {ch.rmse:.2f} K = {ch.rmse / s.sigma[i]:.1f} noise levels "
             f"(Ljung-Box p = {ch.ljung_box_p:.2g})" for i, ch in enumerate(s.channels)]
    if lab.n:
        parts.append(f"lab RMSE {lab.rmse:.4f} kg/kg = {lab.rmse / s.sigma[2]:.1f} noise "
                     f"levels over {lab.n} results")
    return "baseline residuals: " + ", ".join(parts)


def score_text(fitted: Fitted, sc: Score) -> str:
    """The fitted extension and its held-out numbers."""
    b, e = sc.baseline, sc.extended
    rm = ", ".join(f"{n} {_fmt_unit(n, b.rmse[n])} -> {_fmt_unit(n, e.rmse[n])}"
                   for n in OUTPUT_NAMES if b.n[n])
    ll = ", ".join(f"{n} {sc.loglik[n]:+.1f}" for n in OUTPUT_NAMES if b.n[n])
    text = (f"fitted: {fitted.description}. Held out, each part of the day predicted by the "
            f"fit on the other part ({b.n['T_dryer_out']} windows, {b.n['moisture_out']} lab "
            f"results): RMSE {rm}; cost {b.cost:.4f} -> {e.cost:.4f} (gain {sc.gain:+.3f}; "
            f"on the last part alone {sc.split_gain:+.3f}); against the calibration error "
            f"(whitened, whole day), log-likelihood gain {ll}, penalised for {sc.n_params} "
            f"parameter(s) {sc.penalised:+.1f}; likelihood ratio {sc.lr:.1f} "
            f"(p = {sc.p_value:.2g})")
    why = sc.why_not()
    return text + (f". Not eligible: {why}" if why else ". Eligible")


def shape_text(fit: ShapeFit) -> str:
    """A cause's shape on the residuals (:mod:`.shapes`) and its evidence, in words."""
    left = (f"{fit.structure_left:+.1f}" if math.isfinite(fit.structure_left) else "n/a")
    return (f"{fit.description}; log Bayes factor against the normal {fit.log_bayes:+.1f} "
            f"nats (Occam factor included), structure left {left} nats")


def evidence_text(cause: str, summary: ResidualSummary, fitted: Fitted | None,
                  sc: Score | None, structure: str | None = None) -> str:
    """The whole evidence string of one ranking entry."""
    text = statistics_text(cause, summary)
    if fitted is not None and sc is not None:
        text += ". " + score_text(fitted, sc)
    elif cause == "unexplained" and structure:
        text += f". Structured: {structure}; no extension is eligible"
    elif cause == "none":
        text += ". The unextended calibrated model"
    return text
