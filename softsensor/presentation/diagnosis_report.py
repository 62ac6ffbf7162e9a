"""The diagnosis page (``softsensor diagnose --report DIR``): PNG figures and an HTML page.

* ``residuals.png``: baseline residuals of every channel over the day (window means for the
  temperatures, lab results at their stamped sample times), with the winning extension's
  residuals on top and the split marked (the extension as scored: each part of the day
  predicted by the fit on the other part);
* ``trajectories.png``: measurements, the calibrated model and the model with the winning
  extension (as scored);
* ``gain.png``: held-out gain (1 - extended cost / baseline cost) and penalised log-likelihood
  gain of every extension, eligible ones highlighted;
* ``index.html``: a plain-language verdict first (:func:`softsensor.presentation.verdicts.
  diagnosis_verdict`: "the cyclone outlet thermometer reads 2.9 °C high: check it"; first of
  all, where the record cannot tell two causes apart, both), then the statistics, the
  ranking of the causes by probability with the size of each cause this day can show
  (:func:`probability_table`), the evidence table and the figures, embedded (the same page
  layout as the calibration report, :func:`softsensor.presentation.calibration_figures.write_page`).
  The evidence is a table, one row per fitted extension and channel (before, after, change,
  log-likelihood gain, eligible or why not; :func:`evidence_table`), and the prose evidence
  of every ranking entry follows under "Details" (:func:`details`).

What a person reads is in plant units (:mod:`softsensor.presentation.display`, the ``[display]``
table): °C, moisture in % on the display basis, time axes in the plant's local clock time; the
program keeps SI everywhere else.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from softsensor.diagnosis.diagnose_day import Diagnosis  # noqa: E402
from softsensor.diagnosis.verdict import MIN_GAIN, MIN_PENALISED, Score  # noqa: E402
from softsensor.errors import ConfigError  # noqa: E402
from softsensor.presentation.calibration_figures import (  # noqa: E402
    clock_axis,
    markdown_table,
    write_page,
)
from softsensor.presentation.display import (  # noqa: E402
    DisplaySettings,
    celsius,
    display_settings,
    lab_reference,
    local_times,
    moisture_pct,
    moisture_pct_points,
    plant_error,
)
from softsensor.presentation.verdicts import cannot_tell_sentence, diagnosis_verdict  # noqa: E402
from softsensor.signals import OUTPUT_NAMES  # noqa: E402


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def residual_figure(d: Diagnosis, path: Path) -> Path:
    """Residuals per channel, baseline and winning extension, split marked."""
    p = d.problem
    w = p.windows
    disp = display_settings(p.config)
    t = local_times(w.end_ns, disp)
    t_lab = local_times(w.lab_time_ns, disp)
    t_split = t[p.split.k_fit - 1]
    base = p.residuals(p.baseline)

    def points(r: np.ndarray) -> np.ndarray:
        """A lab residual [kg/kg dry] as % points on the display basis, at the lab value."""
        x = w.lab_value
        return moisture_pct(x, disp.moisture_basis) - moisture_pct(x - r, disp.moisture_basis)

    win = d.winner
    ext = p.residuals(d.cross_fitted(win.cause)) if win is not None else None
    fig, axes = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True)
    for c, ax in enumerate(axes[:2]):
        ax.plot(t, base.T[:, c], ".", ms=3, color="tab:red", label="calibrated model")
        if ext is not None:
            ax.plot(t, ext.T[:, c], ".", ms=3, color="tab:blue",
                    label=f"with {win.cause} extension")
        for s in (1, -1):
            ax.axhline(s * 2 * d.sigma[c], color="0.6", ls=":", lw=0.8)
    axes[2].plot(t_lab, points(base.lab), "s", ms=5, color="tab:red", label="calibrated model")
    if ext is not None:
        axes[2].plot(t_lab, points(ext.lab), "o", ms=4, color="tab:blue",
                     label=f"with {win.cause} extension")
    x_mid = float(np.median(w.lab_value)) if w.lab_value.size else 0.1
    for s in (1, -1):
        axes[2].axhline(moisture_pct_points(s * 2 * d.sigma[2], x_mid, disp.moisture_basis),
                        color="0.6", ls=":", lw=0.8)
    units = {"T_dryer_out": "°C", "T_cyclone_out": "°C",
             "moisture_out": f"{disp.moisture_unit} points"}
    for ax, name in zip(axes, OUTPUT_NAMES, strict=True):
        ax.axvline(t_split, color="k", ls="--", lw=1,
                   label="split (each side scored by the fit on the other)")
        ax.axhline(0.0, color="0.3", lw=0.6)
        ax.set_ylabel(f"{name} residual [{units[name]}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    clock_axis(axes[-1], disp)
    axes[0].set_title(f"Measured minus model; dotted: 2 noise levels; verdict: {d.cause}")
    axes[-1].set_xlabel(f"local time ({disp.time_zone})")
    return _save(fig, path)


def trajectory_figure(d: Diagnosis, path: Path) -> Path:
    """Measurements, calibrated model and extended model."""
    p = d.problem
    w = p.windows
    disp = display_settings(p.config)
    basis = disp.moisture_basis
    t = local_times(w.end_ns, disp)
    win = d.winner
    pred = d.cross_fitted(win.cause) if win is not None else None
    fig, axes = plt.subplots(3, 1, figsize=(11, 8.5), sharex=True)
    for c, ax in enumerate(axes[:2]):
        ax.plot(t, celsius(w.Y[:, c]), ".", ms=3, color="0.4", label="measured (600 s mean)")
        ax.plot(t, celsius(p.baseline.Y[:, c]), "-", lw=1.1, color="tab:red",
                label="calibrated model")
        if win is not None:
            ax.plot(t, celsius(pred.Y[:, c]), "-", lw=1.1, color="tab:blue",
                    label=f"with {win.cause} extension")
    t_mid = local_times(w.end_ns - int(0.5 * w.window_s * 1e9), disp)
    axes[2].plot(local_times(w.lab_time_ns, disp), moisture_pct(w.lab_value, basis), "s",
                 ms=5, color="tab:green", label="lab (stamped sample time)")
    axes[2].plot(t_mid, moisture_pct(p.baseline.Y[:, 2], basis), "-", lw=1.1,
                 color="tab:red", label="calibrated model")
    if win is not None:
        axes[2].plot(t_mid, moisture_pct(pred.Y[:, 2], basis), "-", lw=1.1, color="tab:blue",
                     label=f"with {win.cause} extension")
    units = {"T_dryer_out": "°C", "T_cyclone_out": "°C", "moisture_out": disp.moisture_unit}
    for ax, name in zip(axes, OUTPUT_NAMES, strict=True):
        ax.axvline(t[p.split.k_fit - 1], color="k", ls="--", lw=1)
        ax.set_ylabel(f"{name} [{units[name]}]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    clock_axis(axes[-1], disp)
    axes[0].set_title("Trajectories before and after the winning extension (dashed: the "
                      "split; each side predicted by the fit on the other)")
    axes[-1].set_xlabel(f"local time ({disp.time_zone})")
    return _save(fig, path)


def gain_figure(d: Diagnosis, path: Path) -> Path:
    """Held-out gain and penalised log-likelihood gain per extension."""
    causes = list(d.scores)
    sc = [d.scores[c] for c in causes]
    colors = ["tab:green" if s.eligible else "0.6" for s in sc]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    axes[0].barh(causes, [s.gain for s in sc], color=colors)
    axes[0].axvline(0.0, color="k", lw=0.8)
    axes[0].set_xlabel("held-out gain = 1 - extended cost / baseline cost (cross-fitted)")
    pen = np.array([s.penalised for s in sc])
    axes[1].barh(causes, np.sign(pen) * np.log10(1.0 + np.abs(pen)), color=colors)
    axes[1].axvline(0.0, color="k", lw=0.8)
    axes[1].set_xlabel("penalised held-out log-likelihood gain P, sign * log10(1 + |P|)")
    axes[1].set_yticks([])
    for ax in axes:
        ax.grid(alpha=0.3, axis="x")
    fig.suptitle(f"Extensions scored on data they were not fitted on (green: eligible); "
                 f"verdict: {d.cause}")
    return _save(fig, path)


#: The columns of the evidence table: one row per scored extension and channel.
EVIDENCE_COLUMNS = ("cause", "channel", "unit", "before", "after", "change",
                    "log-lik. gain", "eligible / why not")

#: What the evidence table's numbers are (printed above it).
EVIDENCE_NOTE = (
    "Every extension that was fitted, in the order of the ranking, one row per channel. "
    "*before*: RMSE of the calibrated model over the day; *after*: RMSE with the extension, "
    "each part of the day predicted by the extension fitted on the other part; *change*: "
    "after against before; *log-lik. gain*: what the extension explains on that channel "
    "beyond the slow error the calibration leaves (whitened log-likelihood gain, positive: "
    "better). An extension is eligible when it is significant, its penalised gain P (the "
    f"channels' gains less one per fitted parameter) is at least {MIN_PENALISED:g}, it makes "
    f"no channel worse and it lowers the paper's cost (eq. 4) by more than {MIN_GAIN:.0%}.")


def why_not_short(sc: Score) -> str:
    """``eligible``, or why not in a few words (:meth:`Score.failed_checks
    <softsensor.diagnosis.verdict.Score.failed_checks>`; :meth:`~softsensor.diagnosis.
    verdict.Score.why_not` says it in full)."""
    return "; ".join(short for short, _ in sc.failed_checks()) or "eligible"


def _cell(text: str) -> str:
    return text.replace("|", "/")


def evidence_table(d: Diagnosis, doc: dict, plant: Callable[[str, float | None], str],
                   x_ref: float, disp: DisplaySettings) -> str:
    """The evidence as a table (:data:`EVIDENCE_COLUMNS`): per scored extension, in the
    ranking's order, and channel the cross-fitted RMSE before and after in plant units
    (:func:`~softsensor.presentation.display.plant_error`), its change, the log-likelihood gain
    against
    the calibration error and whether the extension is eligible."""
    rows = []
    for r in doc["ranking"]:
        sc = d.scores.get(r["cause"])
        if sc is None:
            continue
        status = _cell(why_not_short(sc))
        rel = sc.relative
        for n in OUTPUT_NAMES:
            change = f"{0.0 - 100.0 * rel[n]:+.1f} %" if np.isfinite(rel[n]) else "n/a"
            ll = sc.loglik[n]
            rows.append([r["cause"], n, _cell(plant_error(n, 0.0, x_ref, disp)[1]),
                         plant(n, sc.baseline.rmse[n]), plant(n, sc.extended.rmse[n]),
                         change, f"{ll:+.1f}" if np.isfinite(ll) else "n/a", status])
    if not rows:
        return "No extension was fitted."
    return markdown_table(EVIDENCE_COLUMNS, rows)


#: The columns of the probability ranking.
PROBABILITY_COLUMNS = ("rank", "cause", "channel", "probability", "log-evidence [nats]",
                       "smallest size this day can show")

#: What the probability ranking is (printed above it).
PROBABILITY_NOTE = (
    "Every cause with its probability: a softmax over the causes' penalised held-out "
    "log-likelihood gains against the plant's normal (or, where larger, the marginal "
    "evidence of the shape the cause leaves on the residuals), each charged for the gain a "
    "clean day reaches, `unexplained` for what the normal's noise allows, its temperature "
    "fitted on tuning days. *Smallest size this day can show*: the size at which the cause's "
    "trace on this day, seen through the plant's normal, is large enough to be named; a "
    "cause smaller than that is beyond what this record can show.")


def probability_table(doc: dict) -> str:
    """The causes by probability (:data:`PROBABILITY_COLUMNS`), with the detectable size of
    each cause on the day (REPORT.json ``detectability``)."""
    det = doc.get("detectability") or {}
    rows = []
    for i, c in enumerate(doc.get("probabilities") or [], 1):
        d = det.get(c["cause"])
        size = "n/a" if d is None else (
            "not at any size" if d.get("detectable_size") is None
            else f"{d['detectable_size']:.3g} {d['unit']}")
        rows.append([str(i), c["cause"], c.get("channel") or "", f"{c['probability']:.3f}",
                     f"{c['log_evidence']:+.1f}", _cell(size)])
    if not rows:
        return "No probabilities."
    return markdown_table(PROBABILITY_COLUMNS, rows)


def details(doc: dict) -> str:
    """The prose evidence of every ranking entry, as a list (what the table leaves out)."""
    items = []
    for r in doc["ranking"]:
        nums = [f"score {r['score']:.3f}"]
        if r.get("gain") is not None:
            nums.append(f"held-out gain {r['gain']:+.3f}")
        if r.get("penalised_loglik_gain") is not None:
            nums.append(f"P {r['penalised_loglik_gain']:+.1f}")
        items.append(f"- **{r['cause']}** ({', '.join(nums)}): {r['evidence']}")
    return "\n".join(items)


def write_report(d: Diagnosis, directory: str | Path, report: dict | None = None) -> Path:
    """Write the figures and ``index.html`` into ``directory`` (created); returns the page."""
    out = Path(directory)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--report {out}: cannot create the directory: {exc.strerror}") \
            from exc
    doc = report if report is not None else d.to_json()
    residual_figure(d, out / "residuals.png")
    trajectory_figure(d, out / "trajectories.png")
    gain_figure(d, out / "gain.png")
    disp = display_settings(d.problem.config)
    x_ref = lab_reference([d.problem.windows])

    def plant(n: str, v: float | None) -> str:
        if v is None or not np.isfinite(v):
            return "n/a"
        return f"{plant_error(n, v, x_ref, disp)[0]:.3g}"

    rm = markdown_table(["channel", "unit", "baseline RMSE", "extended RMSE"],
                        [[n, plant_error(n, 0.0, x_ref, disp)[1],
                          plant(n, doc["baseline_rmse"][n]), plant(n, doc["extended_rmse"][n])]
                         for n in OUTPUT_NAMES])
    stats = (f"**Cause: `{doc['cause']}`**"
             + (f" on `{doc['channel']}`" if doc.get("channel") else "")
             + f". Held-out cost (paper eq. 4; each part of the day predicted by the "
             f"extension fitted on the other part) {doc['baseline_cost']:.4f} -> "
             f"{doc['extended_cost']:.4f}, gain {doc['gain']:+.3f}. "
             f"{doc['held_out']['note']}.")
    if doc.get("extension"):
        stats += f" Extension: {doc['extension']['description']}."
    if doc.get("structure"):
        stats += f" Baseline residuals structured: {doc['structure']}."
    undecided = cannot_tell_sentence(doc)
    sections = [
        ("Statistics", stats + "\n\n" + rm),
        ("Probability of every cause", ((undecided + "\n\n") if undecided else "")
         + PROBABILITY_NOTE + "\n\n" + probability_table(doc)),
        ("Evidence", EVIDENCE_NOTE + "\n\n" + evidence_table(d, doc, plant, x_ref, disp)),
        ("Details", details(doc)),
        ("Residuals per channel", "![residuals](residuals.png)"),
        ("Trajectories before and after the extension", "![trajectories](trajectories.png)"),
        ("Held-out gain of every extension", "![gain](gain.png)"),
    ]
    return write_page(out, f"Diagnosis of {doc.get('day', 'the day')}", sections,
                      verdict=diagnosis_verdict(doc))

