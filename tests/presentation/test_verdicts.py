"""Plain-language verdicts (``softsensor/presentation/verdicts.py``, issue 13): the diagnosis'
and the calibration's sentences in plant units. The page they head:
``test_calibration_figures.py``."""

from __future__ import annotations

import pytest

from softsensor.presentation.verdicts import calibration_verdict, diagnosis_verdict


def _doc(cause: str, params: dict, channel: str | None = None, gain: float = 0.42) -> dict:
    return {"cause": cause, "channel": channel, "gain": gain,
            "ranking": [{"cause": "none", "params": None},
                        {"cause": cause, "params": params}]}


@pytest.mark.parametrize(("offset", "word"), [(2.9, "high"), (-1.6, "low")])
def test_sensor_bias_names_the_thermometer_the_size_and_the_side(offset, word):
    text = diagnosis_verdict(_doc("sensor_bias", {"offset_K": offset}, "T_cyclone_out"))
    assert text.startswith(f"The cyclone outlet thermometer (T_cyclone_out) reads "
                           f"{abs(offset):.1f} °C {word}: check it")
    assert "42 % better" in text


@pytest.mark.parametrize(("cause", "params", "needles"), [
    ("lab_delay", {"shift_min": 35.0}, ("35 min later", "LIMS")),
    ("lab_delay", {"shift_min": -20.0}, ("20 min earlier",)),
    ("fouling_drift", {"loss_by_end": 0.3}, ("fell by about 30%", "fouling")),
    ("input_lag", {"tau_min": 6.2}, ("lags the air by about 6 min", "T_air_in")),
    ("ambient_heat_loss", {"beta_amb_per_K": 0.03}, ("+30% per 10 °C colder",)),
    ("inlet_moisture", {"walk_per_sqrt_h": 0.02}, ("inlet fibre moisture",)),
])
def test_each_cause_reads_in_plant_units(cause, params, needles):
    text = diagnosis_verdict(_doc(cause, params))
    for n in needles:
        assert n in text, text


def test_none_and_unexplained_say_what_to_do():
    assert "nothing to check" in diagnosis_verdict({"cause": "none", "ranking": []})
    assert "none of the known causes" in diagnosis_verdict({"cause": "unexplained"})


def test_cannot_tell_says_both_and_what_would_separate_them():
    """Issue 39 item 3: a pair without signatures to compare (an extension against
    ``unexplained``) is said as evidence that does not separate them, with the data that
    would; two collinear signatures as the same trace."""
    pair = [{"cause": "lab_delay", "channel": None, "probability": 0.41},
            {"cause": "unexplained", "channel": None, "probability": 0.33}]
    doc = {"cause": "lab_delay", "ranking": [], "cannot_tell": pair,
           "cannot_tell_collinearity": None,
           "cannot_tell_separate": "for lab_delay, lab samples while the moisture moves"}
    text = diagnosis_verdict(doc)
    assert text.startswith("This record cannot tell lab_delay (probability 41%) from "
                           "unexplained (33%): on this day its evidence does not separate "
                           "them; check both. What would separate them: for lab_delay, lab "
                           "samples while the moisture moves."), text
    same = dict(doc, cannot_tell_collinearity=0.97, cannot_tell_separate=None)
    assert "both would leave nearly the same trace in the data; check both." in \
        diagnosis_verdict(same)


def test_calibration_verdict_in_celsius_and_moisture_points():
    old = {"T_dryer_out": 2.5, "T_cyclone_out": 3.0, "moisture_out": 0.02}
    new = {"T_dryer_out": 0.8, "T_cyclone_out": 0.9, "moisture_out": 0.01}
    text = calibration_verdict(new, old, True, ["hm_cyc"], 0.1, "dry")
    assert text.startswith("New parameters written.")
    assert "2.50 -> 0.80 °C" in text and "2.00 -> 1.00 % points (dry basis)" in text
    assert "hm_cyc" in text
    assert calibration_verdict(new, old, False, [], 0.1).startswith("New parameters NOT")


