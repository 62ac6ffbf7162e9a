"""Plain-language verdicts and the self-contained report page (issue 13, reports a plant
engineer reads)."""

from __future__ import annotations

import base64

import pytest

from softsensor.presentation.calibration_figures import markdown_table, write_page
from softsensor.presentation.display import moisture_pct, moisture_pct_points
from softsensor.presentation.verdicts import calibration_verdict, diagnosis_verdict


def _doc(cause: str, params: dict, channel: str | None = None, gain: float = 0.42) -> dict:
    return {"cause": cause, "channel": channel, "gain": gain,
            "ranking": [{"cause": "none", "params": None},
                        {"cause": cause, "params": params}]}


def test_moisture_in_percent_on_either_basis():
    assert moisture_pct(0.1, "dry") == pytest.approx(10.0)
    assert moisture_pct(0.1, "wet") == pytest.approx(100 * 0.1 / 1.1)
    assert moisture_pct(1.0, "wet") == pytest.approx(50.0)
    assert moisture_pct_points(0.01, 0.1, "dry") == pytest.approx(1.0)
    assert moisture_pct_points(0.01, 0.1, "wet") == pytest.approx(100 * (0.11 / 1.11 - 0.1 / 1.1))
    with pytest.raises(ValueError, match="basis"):
        moisture_pct(0.1, "as received")


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


def test_calibration_verdict_in_celsius_and_moisture_points():
    old = {"T_dryer_out": 2.5, "T_cyclone_out": 3.0, "moisture_out": 0.02}
    new = {"T_dryer_out": 0.8, "T_cyclone_out": 0.9, "moisture_out": 0.01}
    text = calibration_verdict(new, old, True, ["hm_cyc"], 0.1, "dry")
    assert text.startswith("New parameters written.")
    assert "2.50 -> 0.80 °C" in text and "2.00 -> 1.00 % points (dry basis)" in text
    assert "hm_cyc" in text
    assert calibration_verdict(new, old, False, [], 0.1).startswith("New parameters NOT")


def test_page_is_one_file_with_figures_inside_and_text_escaped(tmp_path):
    png = base64.b64decode("iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk"
                           "YPhfDwAChwGA60e6kgAAAABJRU5ErkJggg==")
    (tmp_path / "fig.png").write_bytes(png)
    page = write_page(tmp_path, "Day <script>x</script>", [
        ("Table", markdown_table(["a", "b"], [[1, "<b>2</b>"]])),
        ("Figure", "![](fig.png)")], verdict="Check the <thermometer> & wiring")
    html = page.read_text()
    assert page.name == "index.html"
    assert "<script>" not in html and "&lt;script&gt;" in html
    assert "&lt;thermometer&gt; &amp; wiring" in html and "<b>2</b>" not in html
    assert html.index('class="verdict"') < html.index("<h2>")
    assert "<table>" in html and "<td>1</td>" in html
    assert 'src="data:image/png;base64,' + base64.b64encode(png).decode() + '"' in html
