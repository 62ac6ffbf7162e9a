"""Plain-language verdicts for the people who run the dryer: what the program found and what
to check, in plant units (°C, % moisture, minutes), first on every report page and in the
one-line summary a verb prints on stderr.

The statistics behind each sentence stay below it on the page and in the JSON (SI there,
docs/interface.md section 5). Moisture is given in % on the basis the reader chooses: ``wet``
(w = X / (1 + X), what most plants' labs report) or ``dry`` (X, the program's kg/kg).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from softsensor.presentation.display import moisture_pct_points

#: What each thermometer is called on the plant floor.
SENSOR_NAMES: dict[str, str] = {
    "T_dryer_out": "dryer outlet thermometer (T_dryer_out)",
    "T_cyclone_out": "cyclone outlet thermometer (T_cyclone_out)",
    "T_air_in": "inlet air thermometer (T_air_in)",
}


def _params(doc: Mapping[str, Any]) -> dict[str, float]:
    for r in doc.get("ranking", []):
        if r.get("cause") == doc.get("cause"):
            return dict(r.get("params") or {})
    return {}


def _sensor_bias(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    b = float(p.get("offset_K", math.nan))
    name = SENSOR_NAMES.get(str(doc.get("channel")), f"{doc.get('channel')} thermometer")
    side = "high" if b > 0 else "low"
    if doc.get("channel") == "T_dryer_out":
        # the loop's own thermometer: the loop holds its reading, so the process moves
        run = "colder" if b > 0 else "hotter"
        return (f"The {name}, the one the outlet-temperature loop holds at its set point, "
                f"reads {abs(b):.1f} °C {side}: the loop then runs the dryer about "
                f"{abs(b):.1f} °C {run} than the set point, and the cyclone outlet and the labs "
                f"follow that process, not the reading. Check the thermometer (calibration, "
                f"thermowell, wiring) before trusting the loop or the estimates that use it.")
    return (f"The {name} reads {abs(b):.1f} °C {side}: check it (calibration, thermowell, "
            f"wiring) before trusting it or the estimates that use it.")


def _lab_delay(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    m = float(p.get("shift_min", math.nan))
    when = "later" if m > 0 else "earlier"
    return (f"The lab samples look to have been taken about {abs(m):.0f} min {when} than "
            f"their recorded sample time: check how sample times are entered in the LIMS "
            f"(clock, time zone, result time used as sample time).")


def _fouling(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    d = float(p.get("loss_by_end", math.nan))
    trend = "fell" if d >= 0 else "rose"
    return (f"Heat and mass transfer in the dryer tube {trend} by about {abs(d):.0%} over the "
            f"record: the tube may be fouling; compare with the last cleaning.")


def _lag(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    tau = float(p.get("tau_min", math.nan))
    return (f"The {SENSOR_NAMES['T_air_in']} lags the air by about {tau:.0f} min: check its "
            f"thermowell and mounting (a slow sensor misleads the model and the controller).")


def _ambient(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    if "dT_cyclone_out_per_10K" in p:  # named by its shape on the residuals
        return (f"Heat loss to the outside changes with the weather more than the model says "
                f"(the outlet temperatures read {float(p['dT_dryer_out_per_10K']):+.1f} °C and "
                f"{float(p['dT_cyclone_out_per_10K']):+.1f} °C off the model per 10 °C of "
                f"cold below 10 °C): check the cladding and insulation of the tube and "
                f"cyclones.")
    beta = float(p.get("beta_amb_per_K", math.nan))
    return (f"Heat loss to the outside changes with the weather more than the model says "
            f"({beta * 10:+.0%} per 10 °C colder): check the cladding and insulation of the "
            f"tube and cyclones.")


def _inlet(p: Mapping[str, float], doc: Mapping[str, Any]) -> str:
    return ("The inlet fibre moisture varied during the record more than the model assumed: "
            "watch the estimated inlet moisture and check the chip supply and steaming.")


_SENTENCES: dict[str, Callable[[Mapping[str, float], Mapping[str, Any]], str]] = {
    "sensor_bias": _sensor_bias, "lab_delay": _lab_delay, "fouling_drift": _fouling,
    "input_lag": _lag, "ambient_heat_loss": _ambient, "inlet_moisture": _inlet,
}


def _cause_words(entry: Mapping[str, Any]) -> str:
    return str(entry.get("cause")) + (f" on {entry['channel']}" if entry.get("channel") else "")


#: ``|cos|`` of two signatures above which the sentence says both leave the same trace.
SAME_TRACE = 0.9


def cannot_tell_sentence(doc: Mapping[str, Any]) -> str:
    """The sentence that names both causes the record cannot tell apart (REPORT.json
    ``cannot_tell``), or ``""``."""
    both = list(doc.get("cannot_tell") or [])
    if len(both) < 2:
        return ""
    a, b = both[0], both[1]
    cos = doc.get("cannot_tell_collinearity")
    why = ("both would leave nearly the same trace in the data" if cos is not None
           and float(cos) >= SAME_TRACE else "its evidence does not separate them")
    separate = doc.get("cannot_tell_separate")
    return (f"This record cannot tell {_cause_words(a)} (probability "
            f"{float(a['probability']):.0%}) from {_cause_words(b)} "
            f"({float(b['probability']):.0%}): on this day {why}; check both"
            + (f". What would separate them: {separate}." if separate else "."))


def diagnosis_verdict(doc: Mapping[str, Any]) -> str:
    """The diagnosis (REPORT.json, docs/interface.md section 5) as one or two sentences;
    with too little history to know the plant's normal, that is said first (and a cause
    only leaned to); where the record cannot tell two causes apart, that is said next."""
    undecided = cannot_tell_sentence(doc)
    text = (undecided + " " + _named_verdict(doc)) if undecided else _named_verdict(doc)
    short = too_little_history_sentence(doc)
    if short is None:
        return text
    lean = "" if doc.get("cause") == "none" else "The evidence leans to this, no more: "
    return f"{short} {lean}{text}"


def too_little_history_sentence(doc: Mapping[str, Any]) -> str | None:
    """What REPORT.json's ``plant_normal`` says when there were too few history days to
    know the plant's normal (None when there were enough, or no such field)."""
    note = doc.get("plant_normal")
    if not note or note.get("enough", True):
        return None
    n, need = int(note.get("history_days", 0)), int(note.get("min_history_days", 0))
    cap = note.get("cap")
    capped = "" if cap is None else f"; no cause is given a probability above {float(cap):.2f}"
    return (f"Too little history to know this plant's normal ({n} history day(s) judged, "
            f"{need} needed: `softsensor learn-normal`){capped}.")


def _named_verdict(doc: Mapping[str, Any]) -> str:
    cause = doc.get("cause")
    if cause == "none":
        return ("The calibrated model explains this record to within the sensors' noise: "
                "nothing to check.")
    if cause == "unexplained":
        text = ("The model misses this record in a way none of the known causes explains: "
                "look at the residual figures below and at what changed in the plant.")
        refuted = next((r.get("contradicted") for r in doc.get("ranking", [])
                        if r.get("cause") == "inlet_moisture" and r.get("contradicted")), None)
        if refuted:
            text += (" The outlet temperatures moved as an inlet-moisture change would move "
                     "them, but the labs did not follow: look first for an unmeasured change "
                     "of air flow (fan, dampers, a flow meter stuck) or of heat input.")
        return text
    sentence = _SENTENCES.get(str(cause))
    if sentence is None:
        return f"Cause found: {cause}."
    gain = doc.get("gain")
    tail = "" if gain is None else (f" Accounting for it predicts the held-out part of the "
                                    f"record {100 * float(gain):.0f} % better.")
    if doc.get("shape"):
        # named by the shape it leaves on the residuals, not by a model extension's
        # held-out gain (there is none to quote)
        tail = (" Named from the shape it leaves on the residuals against this plant's "
                "normal; the model's own extension for it did not improve the held-out part.")
    return sentence(_params(doc), doc) + tail


def calibration_verdict(rmse_new: Mapping[str, float] | None,
                        rmse_old: Mapping[str, float] | None, written: bool,
                        at_bounds: list[str], x_ref: float, basis: str = "wet",
                        where: str = "held-out data") -> str:
    """The calibration's outcome in plant units: the errors on ``where`` before and after,
    and whether the parameters were written. ``x_ref`` [kg/kg dry] is the moisture at which
    kg/kg errors are turned into % points."""
    head = ("New parameters written." if written
            else "New parameters NOT written: they predict the held-out data worse.")
    parts = [head]
    if rmse_new and rmse_old:
        def k(name: str) -> str:
            return f"{rmse_old[name]:.2f} -> {rmse_new[name]:.2f} °C"

        m_old = moisture_pct_points(rmse_old["moisture_out"], x_ref, basis)
        m_new = moisture_pct_points(rmse_new["moisture_out"], x_ref, basis)
        parts.append(f"Errors on the {where} (RMSE, current -> calibrated): dryer outlet "
                     f"{k('T_dryer_out')}, cyclone outlet {k('T_cyclone_out')}, outlet "
                     f"moisture {m_old:.2f} -> {m_new:.2f} % points ({basis} basis).")
    if at_bounds:
        parts.append(f"At a search bound (not pinned by the data): {', '.join(at_bounds)}.")
    return " ".join(parts)


#: How a channel is called in the validation's sentences.
_CHANNEL_WORDS: dict[str, str] = {"T_dryer_out": "dryer outlet", "T_cyclone_out": "cyclone outlet",
                                  "moisture_out": "outlet moisture"}


def _errors(rmse: Mapping[str, float], x_ref: float, basis: str) -> str:
    pts = moisture_pct_points(rmse["moisture_out"], x_ref, basis)
    return (f"dryer outlet {rmse['T_dryer_out']:.2f} °C, cyclone outlet "
            f"{rmse['T_cyclone_out']:.2f} °C and outlet moisture {pts:.2f} % points "
            f"({basis} basis)")


def open_loop_sentence(summary: Mapping[str, Any], x_ref: float, basis: str = "wet") -> str:
    """The open-loop errors (:func:`softsensor.calibration.open_loop_errors.open_loop_summary`) in
    plant units (°C, % points on ``basis`` at the moisture ``x_ref`` [kg/kg dry]), with the
    inlet level they hold: what ``validate`` says first and ``diagnose`` says of the same
    model on the same day."""
    normal = ", with the history's normal" if summary.get("normal") else ""
    return (f"Open loop (inlet moisture held at {summary['inlet_moisture']:.2f} kg/kg, the "
            f"calibration's level{normal}) the model's errors (RMSE) are "
            f"{_errors(summary['rmse'], x_ref, basis)}.")


def held_out_verdict(summary: Mapping[str, Any], decisive: bool = True) -> str:
    """Each channel's open-loop error against the calibration's own held-out error
    (``summary['verdict']``, :func:`softsensor.calibration.open_loop_errors.channel_verdicts`).
    Not ``decisive`` (the sensor's mode is judged beside it, :func:`validation_verdict`): a
    channel off by more than one day scatters says open loop misses these data, never that
    the model does not hold."""
    checks = summary.get("verdict") or {}
    if summary.get("reference") is None:
        return ("No verdict: the parameter file holds no held-out error of its calibration "
                "([model_error] or [fit.validation]).")
    parts, worse = [], []
    for name, words in _CHANNEL_WORDS.items():
        c = checks.get(name) or {}
        ratio, v = c.get("ratio"), c.get("verdict")
        if ratio is None:
            parts.append(f"{words} not known")
        elif v == "within":
            parts.append(f"{words} within it ({ratio:.1f} times)")
        elif v == "spread":
            parts.append(f"{words} {ratio:.1f} times, within what one day scatters")
        else:
            parts.append(f"{words} {ratio:.1f} times worse")
            worse.append(words)
    if worse and decisive:
        tail = f": the model does not hold on these data ({', '.join(worse)})."
    elif worse:
        tail = (f": open loop misses these data ({', '.join(worse)}); the verdict is the "
                f"sensor's mode.")
    else:
        tail = "."
    return "Against the calibration's held-out error: " + "; ".join(parts) + tail


def history_verdict(checks: Mapping[str, Mapping[str, Any]] | None) -> str:
    """The sensor's-mode errors against the plant's own history days in the same mode
    (:func:`softsensor.diagnosis.plant_normal.history_check`), in words: the model holds
    unless a channel lies beyond what the history days showed."""
    known = {n: c for n, c in (checks or {}).items() if c.get("verdict") != "unknown"}
    if not known:
        return ("No verdict: no history days were judged for these parameters in this mode "
                "(`softsensor learn-normal` keeps them beside PARAMS.toml).")
    days = max(int(c.get("days", 0)) for c in known.values())
    parts, beyond = [], []
    for name, words in _CHANNEL_WORDS.items():
        c = known.get(name)
        if c is None:
            parts.append(f"{words} not known")
            continue
        if name == "moisture_out":
            a, b = f"{c['rmse']:.4f}", f"{c['upper']:.4f} kg/kg"
        else:
            a, b = f"{c['rmse']:.2f}", f"{c['upper']:.2f} °C"
        parts.append(f"{words} {a} against up to {b}")
        if c["verdict"] == "beyond":
            beyond.append(words)
    tail = (f": the model does not hold on these data ({', '.join(beyond)} beyond its "
            f"history)." if beyond else ": within this plant's history, the model holds.")
    return (f"Against this plant's {days} history days in the same mode: "
            + "; ".join(parts) + tail)


def validation_verdict(open_loop: Mapping[str, Any], inlet_read: Mapping[str, float] | None,
                       x_ref: float, basis: str = "wet",
                       history: Mapping[str, Mapping[str, Any]] | None = None) -> str:
    """What a validation found, in plant units. With the errors in the sensor's mode
    (``inlet_read``: the inlet moisture read from the temperatures, what the sensor does)
    the verdict is theirs, against the spread of the plant's own history days in that mode
    (``history``, :func:`history_verdict`); open loop follows beside it
    (:func:`open_loop_sentence`, against the calibration's held-out error but never
    decisive), then one sentence when the sensor's reading makes the outlet moisture worse
    than open loop. Without ``inlet_read``, open loop and its verdict alone. The
    ``validate`` line and the validation page say this text."""
    if inlet_read is None:
        return f"{open_loop_sentence(open_loop, x_ref, basis)} {held_out_verdict(open_loop)}"
    text = (f"In the sensor's mode (the inlet moisture read from the temperatures) the "
            f"model's errors (RMSE) are {_errors(inlet_read, x_ref, basis)}. "
            f"{history_verdict(history)} Beside it, open loop: "
            f"{open_loop_sentence(open_loop, x_ref, basis)} "
            f"{held_out_verdict(open_loop, decisive=False)}")
    m_open, m_read = open_loop["rmse"]["moisture_out"], inlet_read["moisture_out"]
    if m_read > m_open:
        a, b = (moisture_pct_points(m, x_ref, basis) for m in (m_open, m_read))
        text += (f" Reading the inlet moisture from the temperatures makes the outlet "
                 f"moisture worse than open loop ({a:.2f} -> {b:.2f} % points): the "
                 f"temperatures carry the model's own error, which this reading takes for "
                 f"inlet moisture.")
    return text


def calibration_result_verdict(result: Any, basis: str = "wet") -> str:
    """:func:`calibration_verdict` of a :class:`~softsensor.calibration.calibration_run.
    CalibrationResult`: its held-out errors (its calibration data when nothing was held
    out), at the median lab moisture of its data."""
    import numpy as np

    new, old, where = result.validation, result.current_validation, "held-out data"
    if new is None or old is None:
        new, old, where = result, result.current_evaluation, "calibration data"
    labs = np.concatenate([seg.lab_value for seg in result.segments])
    return calibration_verdict(
        new.fit.rmse, None if old is None else old.fit.rmse, result.accepted,
        result.at_bounds, float(np.median(labs)) if labs.size else 0.1, basis, where=where)


#: What the estimator's health says, in the words of the control room: (keyword found in the
#: health's detail, what it means). The first that matches names the reason; the detail itself
#: stays beside it for the engineer.
_HEALTH_REASONS: tuple[tuple[str, str], ...] = (
    ("stalled", "the estimator is late: no new estimate came when one was due"),
    ("waiting for the first", "starting: waiting for the first complete 10-minute window"),
    ("no estimate yet", "starting: no estimate yet"),
    ("stale window", "too few good PLC scans in the last window: the moisture is predicted "
                     "without the temperatures"),
    ("stale since", "the PLC has sent no usable scans for a while"),
    ("model lost the plant", "the model has lost the plant: the outlet moisture follows the "
                             "last lab result"),
    ("input:", "a measured input is missing or implausible (see the detail)"),
    ("estimator failed", "the estimator failed on the last window"),
    ("innovation", "the outlet temperatures disagree with the model more than usual"),
    ("nis", "the outlet temperatures disagree with the model more than usual"),
    ("no lab result accepted", "no lab result was taken for hours: the estimate runs "
                               "uncorrected (see the last lab refusal)"),
)


def health_words(body: Mapping[str, Any]) -> str:
    """A health body (docs/interface.md section 2: ``status``, ``detail``) as one sentence an
    operator reads without knowing the filter."""
    status = str(body.get("status", "stale"))
    detail = str(body.get("detail") or "").lower()
    if body.get("stalled"):
        detail = "stalled " + detail
    reason = next((text for key, text in _HEALTH_REASONS if key in detail), None)
    if status == "ok":
        return "Reliable: the model follows the measured outlet temperatures."
    if status == "degraded":
        return f"Less certain than usual: {reason or 'see the detail'}."
    return f"No estimate from data: {reason or 'the PLC sends no usable scans'}."


__all__ = ["SENSOR_NAMES", "calibration_result_verdict", "calibration_verdict",
           "cannot_tell_sentence", "diagnosis_verdict", "health_words", "held_out_verdict",
           "history_verdict", "open_loop_sentence", "too_little_history_sentence",
           "validation_verdict"]
