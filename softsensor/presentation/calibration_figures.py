"""Figures a process engineer looks at after a calibration (the paper's Figs. 2 to 6).

Each function writes one PNG (matplotlib, Agg backend, no display needed) and returns its
path; :func:`write_page` puts the figures (embedded) and tables on one self-contained HTML
page, a plain-language verdict first. Times on the axes
of measured data are the plant's local clock time, temperatures °C and moisture % on the
``[display]`` basis (:mod:`softsensor.presentation.display`; the program keeps SI everywhere else);
the model-analysis figures (sensitivities, profiles) keep hours from the start and kg/kg.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import markdown
import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from optuna.trial import TrialState  # noqa: E402

from softsensor.calibration.cost import ModelRun  # noqa: E402
from softsensor.calibration.dataset import Segment  # noqa: E402
from softsensor.calibration.identifiability import Sensitivities  # noqa: E402
from softsensor.files import writing  # noqa: E402
from softsensor.model import DryerModel  # noqa: E402
from softsensor.plantconfig import PARAMETER_NAMES  # noqa: E402
from softsensor.presentation.display import (  # noqa: E402
    DisplaySettings,
    celsius,
    local_times,
    moisture_pct,
    plant_error,
)
from softsensor.signals import OUTPUT_NAMES  # noqa: E402

C0 = 273.15
_UNITS = {"T_dryer_out": "°C", "T_cyclone_out": "°C", "moisture_out": "kg/kg"}


def _hours(seg: Segment) -> np.ndarray:
    return np.arange(1, seg.n_windows + 1) * seg.window / 3600.0


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def sensitivity_figure(sens: Sensitivities, path: str | Path) -> Path:
    """Fig. 2: eq. 5 sensitivity trajectories of each output to each parameter."""
    seg = sens.segment
    t = _hours(seg)
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    for c, (ax, name) in enumerate(zip(axes, OUTPUT_NAMES, strict=True)):
        for i, p in enumerate(PARAMETER_NAMES):
            ax.plot(t, sens.S[:, c, i], label=p, lw=1.2)
        unit = "K" if c < 2 else "kg/kg"
        ax.set_ylabel(f"d {name} / d ln θ [{unit}]")
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.grid(alpha=0.3)
    axes[0].legend(ncol=4, fontsize=8)
    axes[0].set_title("Sensitivity trajectories S_i(t) = θ_i ∂y/∂θ_i (eq. 5)")
    axes[-1].set_xlabel("time [h]")
    return _save(fig, Path(path))


def profile_step_figure(model: DryerModel, theta: np.ndarray, u: np.ndarray,
                        path: str | Path, steps: Sequence[float] = (-40, -20, 0, 20, 40),
                        step_for_dynamics: float = 20.0) -> Path:
    """Fig. 3: the axial temperature profile's response to steps in inlet air temperature.

    Left: steady air and fibre temperature along the tube for ``T_air_in`` stepped by
    ``steps`` [K] around ``u``. Right: the wall profile and outlet air temperature after a
    ``step_for_dynamics`` K step, minute by minute (the wall is the slow state).
    """
    n_d = model.geometry.n_d
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    for dT in steps:
        ui = np.array(u, float)
        ui[0] += dT
        x, _ = model.steady_state(ui, theta)
        prof = model.profiles(x, ui, theta)
        line, = a1.plot(prof["x"][:n_d], prof["T_a"][:n_d] - C0,
                        label=f"T_air_in {ui[0] - C0:.0f} °C")
        a1.plot(prof["x"][:n_d], prof["T_f"][:n_d] - C0, ls="--", color=line.get_color(), lw=0.9)
    a1.set_xlabel("position along the tube [m]")
    a1.set_ylabel("temperature [°C] (solid air, dashed fibre)")
    a1.set_title("Steady axial profile for steps in T_air_in")
    a1.legend(fontsize=8)
    a1.grid(alpha=0.3)
    x0, _ = model.steady_state(u, theta)
    ui = np.array(u, float)
    ui[0] += step_for_dynamics
    minutes = [0, 1, 3, 10, 30]
    state = x0
    T_out = [model.profiles(x0, ui, theta)["T_a"][n_d - 1]]
    shown = {0: x0}
    for m in range(1, max(minutes) + 1):
        Y, state = model.simulate(ui[None], theta, state0=state, dt=60.0)
        T_out.append(float(Y[0, 0]))
        if m in minutes:
            shown[m] = state
    xs = model.profiles(x0, u, theta)["x"][:n_d]
    for m, st in shown.items():
        a2.plot(xs, st[:n_d] - C0, label=f"wall, {m} min after")
    a2.set_xlabel("position along the tube [m]")
    a2.set_ylabel("wall temperature [°C]")
    a2.set_title(f"Wall after a +{step_for_dynamics:g} K step in T_air_in")
    a2.grid(alpha=0.3)
    a2.legend(fontsize=8, loc="upper right")
    inset = a2.inset_axes([0.45, 0.12, 0.5, 0.35])
    inset.plot(np.arange(len(T_out)), np.array(T_out) - C0, color="k")
    inset.set_xlabel("min", fontsize=7)
    inset.set_ylabel("T_dryer_out [°C]", fontsize=7)
    inset.tick_params(labelsize=7)
    return _save(fig, Path(path))


#: What the study's objective is called on the page, by ``[calibration] cost``
#: (:mod:`softsensor.calibration.objective`): the trials' values are this, not eq. 4.
OBJECTIVE_LABELS: dict[str, str] = {
    "likelihood": "objective: negative log-likelihood + prior",
    "eq4": "objective: cost J (eq. 4) + prior",
}


def study_plot(study, importance: Mapping[str, float], cost: str = "likelihood"):
    """Fig. 4 as a matplotlib figure (the caller saves or closes it): the objective the study
    minimised (``cost``, :data:`OBJECTIVE_LABELS`) by trial, every complete trial, the best
    so far as a line, pruned trials at their last partial value; and the importance. On a
    linear axis: a likelihood is negative (a log axis drew 15 of 200 trials and no best-so-far
    line, issue 40)."""
    trials = study.get_trials(deepcopy=False)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7.5))
    comp = [(t.number, t.value) for t in trials if t.state == TrialState.COMPLETE
            and t.value is not None and np.isfinite(t.value)]
    pruned = [(t.number, t.intermediate_values[max(t.intermediate_values)])
              for t in trials if t.state == TrialState.PRUNED and t.intermediate_values
              and not t.user_attrs.get("solver_failed")]
    if comp:
        n, v = np.array(comp).T
        a1.plot(n, v, "o", ms=3, label="complete", gid="complete")
        order = np.argsort(n)
        a1.step(n[order], np.minimum.accumulate(v[order]), "k-", where="post", lw=1.5,
                label="best so far", gid="best")
        # the axis follows the complete trials (a pruned one's partial value may be far off)
        low, high = float(v.min()), float(np.percentile(v, 90))
        pad = 0.05 * (high - low or abs(high) or 1.0)
        a1.set_ylim(low - pad, high + pad)
    if pruned:
        n, v = np.array(pruned).T
        a1.plot(n, v, "x", ms=3, color="0.6", label="pruned (partial value)", gid="pruned")
    a1.set_xlabel("trial")
    a1.set_ylabel(OBJECTIVE_LABELS.get(cost, f"objective ({cost})"))
    a1.set_title("What the study minimised, by trial (lower is better)")
    a1.grid(alpha=0.3)
    a1.legend(fontsize=8)
    names = list(importance)
    a2.barh(names[::-1], [importance[k] for k in names[::-1]])
    a2.set_xlabel("importance (PED-ANOVA, normalised)")
    a2.set_title("Parameter importance")
    return fig


def study_figure(study, importance: Mapping[str, float], path: str | Path,
                 cost: str = "likelihood") -> Path:
    """Fig. 4 (:func:`study_plot`) saved to ``path``."""
    return _save(study_plot(study, importance, cost), Path(path))


def front_plot(trade, display: DisplaySettings, x_ref: float):
    """The multipliers' front as a figure (the caller saves or closes it): the worse outlet
    temperature RMSE against the lab moisture RMSE on the held-out data, in °C and % points
    on the display basis, each point labelled, the deployed and current parameters marked,
    the ``[calibration]`` targets as lines (issue 40: the front was a table only)."""
    fig, ax = plt.subplots(figsize=(7.5, 5))
    unit = plant_error("moisture_out", 0.0, x_ref, display)[1]
    style = {"deployed": ("*", 14, "#d62728"), "current": ("s", 8, "#1f77b4")}
    for p in trade.points:
        if not p.held_out:
            continue
        t = p.worst_temperature()
        m = plant_error("moisture_out", float(p.held_out["moisture_out"]), x_ref, display)[0]
        marker, size, colour = style.get(p.label, ("o", 5, "0.45"))
        ax.plot([t], [m], marker, ms=size, color=colour, gid=p.label,
                label=p.label if p.label in style else None)
        ax.annotate(p.label, (t, m), textcoords="offset points", xytext=(5, 4), fontsize=7)
    ax.axvline(trade.temperature_target, color="#238b45", ls="--", lw=1, gid="target_T",
               label=f"target {trade.temperature_target:g} °C")
    m_target = plant_error("moisture_out", trade.moisture_target, x_ref, display)[0]
    ax.axhline(m_target, color="#238b45", ls=":", lw=1, gid="target_moisture",
               label=f"target {m_target:.2g} {unit}")
    ax.set_xlabel("worse outlet temperature RMSE, held out [°C]")
    ax.set_ylabel(f"lab moisture RMSE, held out [{unit}]")
    ax.set_title("Temperatures against moisture: the multipliers' front")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def front_figure(trade, display: DisplaySettings, x_ref: float, path: str | Path) -> Path:
    """:func:`front_plot` saved to ``path``."""
    return _save(front_plot(trade, display, x_ref), Path(path))


def clock_axis(ax, display: DisplaySettings) -> None:
    """Date axis in the plant's local clock time."""
    loc = mdates.AutoDateLocator(tz=display.zone)
    ax.xaxis.set_major_locator(loc)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc, tz=display.zone))


def trajectory_plot(segments: Sequence[Segment], runs: Sequence[ModelRun], title: str,
                    display: DisplaySettings | None = None):
    """Figs. 5 and 6 as a matplotlib figure (the caller saves or closes it): model against
    measurements, every channel, every segment at its own local clock time; temperatures in
    °C, moisture in % on the display basis. ``runs[s]`` row 0 is the model the fit tables
    score (the inlet moisture fitted, :meth:`~softsensor.calibration.chunked_run.ChunkedRun.
    model_lines`), drawn solid; a row 1 that differs (the nominal inlet moisture, open loop)
    is drawn dashed beside it. The lines carry ``gid`` ``measured``, ``model``,
    ``open_loop``, ``lab`` and ``model_at_lab``."""
    display = display or DisplaySettings()
    basis = display.moisture_basis
    fig, axes = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True)
    for s, (seg, run) in enumerate(zip(segments, runs, strict=True)):
        t = local_times(seg.window_ends_ns(), display)
        first = s == 0
        open_loop = run.Y.shape[0] > 1 and not np.array_equal(run.Y[1], run.Y[0],
                                                                equal_nan=True)
        series = [(run.Y[0], "-", "tab:red", 1.2, "model", "model (inlet moisture fitted)")]
        if open_loop:
            series.append((run.Y[1], "--", "0.45", 0.9, "open_loop",
                           "model, nominal inlet moisture (open loop)"))
        for c, ax in enumerate(axes[:2]):
            ax.plot(t, celsius(seg.Y[:, c]), ".", ms=3, color="tab:blue", gid="measured",
                    label="measured (600 s mean)" if first else None)
            for Y, ls, color, lw, gid, label in series:
                ax.plot(t, celsius(Y[:, c]), ls, color=color, lw=lw, gid=gid,
                        label=label if first else None)
        for Y, ls, color, lw, gid, label in series:
            axes[2].plot(t, moisture_pct(Y[:, 2], basis), ls, color=color, lw=lw, gid=gid,
                         label=label if first else None)
        lab_t = local_times(seg.lab_time_ns, display)
        axes[2].plot(lab_t, moisture_pct(seg.lab_value, basis), "s", ms=5, color="tab:green",
                     gid="lab", label="lab (at sample time)" if first else None)
        axes[2].plot(lab_t, moisture_pct(run.lab[0], basis), "x", ms=6, color="tab:red",
                     gid="model_at_lab", label="model at sample time" if first else None)
    units = {"T_dryer_out": "°C", "T_cyclone_out": "°C", "moisture_out": display.moisture_unit}
    for ax, name in zip(axes, OUTPUT_NAMES, strict=True):
        ax.set_ylabel(f"{name} [{units[name]}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    clock_axis(axes[-1], display)
    axes[0].set_title(title)
    axes[-1].set_xlabel(f"local time ({display.time_zone})")
    return fig


def trajectory_figure(segments: Sequence[Segment], runs: Sequence[ModelRun],
                      path: str | Path, title: str,
                      display: DisplaySettings | None = None) -> Path:
    """:func:`trajectory_plot` written to ``path`` (PNG)."""
    return _save(trajectory_plot(segments, runs, title, display), Path(path))


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(x) for x in r) + " |" for r in rows]
    return "\n".join(out)


_PAGE_STYLE = """
body { font-family: sans-serif; max-width: 70em; margin: 2em auto; color: #222; }
.verdict { font-size: 1.25em; padding: 0.8em 1em; background: #eef4fb;
           border-left: 6px solid #2a6fb0; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: left; }
img { max-width: 100%; }
"""


def _embed_figures(html: str, directory: Path) -> str:
    """``<img src="fig.png">`` of files in ``directory`` as data URIs: one file to send."""
    def inline(m: re.Match[str]) -> str:
        f = directory / m.group(1)
        if not f.is_file():
            return m.group(0)
        data = base64.b64encode(f.read_bytes()).decode("ascii")
        return f'src="data:image/png;base64,{data}"'

    return re.sub(r'src="([^"/]+\.png)"', inline, html)


def write_page(directory: str | Path, title: str, sections: Sequence[tuple[str, str]],
               verdict: str | None = None, name: str = "index.html") -> Path:
    """A self-contained HTML page: ``verdict`` (plain language, first), then ``(heading,
    body)`` sections written in Markdown (tables, ``![](fig.png)`` figures, which are embedded
    in the page). Markdown is rendered by Python-Markdown; text is escaped."""
    d = Path(directory)
    md = markdown.Markdown(extensions=["tables"])
    body = [f"<h1>{html.escape(title)}</h1>"]
    if verdict:
        body.append(f'<p class="verdict">{html.escape(verdict)}</p>')
    for heading, text in sections:
        body.append(f"<h2>{html.escape(heading)}</h2>")
        body.append(md.reset().convert(html.escape(text.rstrip(), quote=False)))
    page = (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_PAGE_STYLE}</style></head>"
            f"<body>\n" + "\n".join(body) + "\n</body></html>\n")
    p = d / name
    with writing(p, "--report") as tmp:
        tmp.write_text(_embed_figures(page, d), encoding="utf-8")
    return p


__all__ = ["OBJECTIVE_LABELS", "clock_axis", "front_figure", "front_plot", "markdown_table",
           "profile_step_figure", "sensitivity_figure", "study_figure", "study_plot",
           "trajectory_figure", "trajectory_plot", "write_page"]
