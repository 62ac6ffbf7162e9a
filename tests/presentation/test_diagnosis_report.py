"""The diagnosis page's evidence is a table a plant engineer reads (issue 22, item 4).

A real, small diagnosis (a 14 h virtual-plant day with a +3 K offset on the dryer outlet
thermometer, two extensions: ``offset_diagnosis`` of ``tests/conftest.py``, the one whose
numbers ``tests/diagnosis/test_diagnose_day.py`` checks) is written as the
``--report`` page; its "Evidence" section must be a table with one row per fitted extension
and channel, in the ranking's order, with the numbers of the extension's
:class:`~softsensor.diagnosis.verdict.Score` in plant units, and the prose evidence must still
be on the page below it.
"""

from __future__ import annotations

import html
import re

import numpy as np
import pytest

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.verdict import Score
from softsensor.presentation.diagnosis_report import why_not_short, write_report
from softsensor.presentation.display import display_settings, plant_error
from softsensor.signals import OUTPUT_NAMES

HEADER = ["cause", "channel", "unit", "before", "after", "change", "log-lik. gain",
          "eligible / why not"]


@pytest.fixture(scope="module")
def diagnosis(offset_diagnosis):
    return offset_diagnosis


@pytest.fixture(scope="module")
def page(diagnosis, tmp_path_factory):
    return write_report(diagnosis, tmp_path_factory.mktemp("report")).read_text()


def _section(page: str, heading: str) -> str:
    start = page.index(f"<h2>{heading}</h2>")
    end = page.find("<h2>", start + 1)
    return page[start:end if end >= 0 else len(page)]


def _cells(row: str) -> list[str]:
    return [html.unescape(re.sub(r"<[^>]+>", "", c)).strip()
            for c in re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", row, re.S)]


def _table(section: str) -> tuple[list[str], list[list[str]]]:
    rows = [_cells(r) for r in re.findall(r"<tr>(.*?)</tr>", section, re.S)]
    return rows[0], rows[1:]


def _text(fragment: str) -> str:
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", fragment)).split())


def test_the_evidence_is_a_table_of_scored_extensions_per_channel(diagnosis, page):
    d = diagnosis
    doc = d.to_json()
    assert d.cause == "sensor_bias" and set(d.scores) == {"sensor_bias", "lab_delay"}
    header, rows = _table(_section(page, "Evidence"))
    assert header == HEADER
    # one row per scored extension and channel, in the ranking's order
    expected = [(r["cause"], n) for r in doc["ranking"] if r["cause"] in d.scores
                for n in OUTPUT_NAMES]
    assert [(r[0], r[1]) for r in rows] == expected
    assert len(rows) == len(OUTPUT_NAMES) * len(d.scores)
    disp = display_settings(d.problem.config)
    x_ref = float(np.median(d.problem.windows.lab_value))
    for row in rows:
        assert len(row) == len(HEADER), row
        cause, name, unit, before, after, change, ll, status = row
        sc = d.scores[cause]
        value, want_unit = plant_error(name, sc.baseline.rmse[name], x_ref, disp)
        assert unit == want_unit
        assert before == f"{value:.3g}", (cause, name)
        assert after == f"{plant_error(name, sc.extended.rmse[name], x_ref, disp)[0]:.3g}"
        assert float(ll) == pytest.approx(sc.loglik[name], abs=0.051)
        assert float(change.rstrip(" %")) == pytest.approx(-100 * sc.relative[name], abs=0.051)
        assert status == why_not_short(sc)
        # short cells, no paragraphs
        assert max(len(c) for c in row) < 60, row
    by = {(r[0], r[1]): r for r in rows}
    # the offset in plant units: 3 °C before, gone after, on the dryer outlet alone
    off = by[("sensor_bias", "T_dryer_out")]
    assert off[2] == "°C" and float(off[3]) == pytest.approx(3.0, abs=0.1)
    assert float(off[4]) < 0.3 and float(off[5].rstrip(" %")) < -80
    assert "% points" in by[("sensor_bias", "moisture_out")][2]
    assert all(by[("sensor_bias", n)][7] == "eligible" for n in OUTPUT_NAMES)
    assert "not significant" in by[("lab_delay", "T_dryer_out")][7]


def test_the_prose_evidence_is_still_on_the_page(diagnosis, page):
    doc = diagnosis.to_json()
    assert page.index("<h2>Evidence</h2>") < page.index("<h2>Details</h2>")
    details = _text(_section(page, "Details"))
    for r in doc["ranking"]:  # every ranking entry, the unextended model too
        assert f"{r['cause']} (score {r['score']:.3f}" in details, r["cause"]
        assert " ".join(r["evidence"].split()) in details, r["cause"]
    # the paragraphs are not in the table
    assert "Held out, each part of the day" not in _section(page, "Evidence")


def _score(*, p=1e-6, penalised=20.0, worse=(), gain=0.1) -> Score:
    h = Fit(rmse={n: 1.0 for n in OUTPUT_NAMES}, n={n: 10 for n in OUTPUT_NAMES}, cost=0.1)
    ll = {n: penalised / 3 for n in OUTPUT_NAMES}
    return Score("sensor_bias", None, 1, h, h, gain, h, h, gain, ll, penalised, tuple(worse),
                 30.0, p)


def test_why_not_is_said_in_a_few_words():
    assert why_not_short(_score()) == "eligible"
    assert why_not_short(_score(p=0.5)) == "not significant"
    assert why_not_short(_score(penalised=3.2)) == "P +3.2 < 10"
    assert why_not_short(_score(worse=("moisture_out",))) == "makes moisture_out worse"
    assert why_not_short(_score(gain=-0.01)) == "eq. 4 gain -0.010 <= 0.05"
    # a positive gain below 5 % is not worth a plant engineer's action (verdict.MIN_GAIN)
    assert why_not_short(_score(gain=0.03)) == "eq. 4 gain +0.030 <= 0.05"
    assert why_not_short(_score(p=0.5, penalised=-1.0, gain=0.0)) == (
        "not significant; P -1.0 < 10; eq. 4 gain +0.000 <= 0.05")


def test_the_page_ranks_the_causes_by_probability(diagnosis, page):
    """Issue 33: the page shows every cause with its probability, most probable first, with
    the size of each cause this day can show; the JSON keeps ``cause``."""
    doc = diagnosis.to_json()
    assert doc["cause"] == "sensor_bias" and doc["channel"] == "T_dryer_out"
    probs = doc["probabilities"]
    assert probs[0]["cause"] == "sensor_bias" and probs[0]["channel"] == "T_dryer_out"
    # a 3 K offset on the matched plant, far above the size this day can show, but judged
    # without any history of this plant (issue 48): the cause leads, at the cap and no more
    cap = doc["plant_normal"]["cap"]
    assert doc["plant_normal"]["enough"] is False and cap == 0.5
    assert probs[0]["probability"] == pytest.approx(cap, abs=1e-6)
    assert probs[0]["probability"] > probs[1]["probability"]
    assert sum(p["probability"] for p in probs) == pytest.approx(1.0, abs=1e-5)
    head, rows = _table(_section(page, "Probability of every cause"))
    assert head == ["rank", "cause", "channel", "probability", "log-evidence [nats]",
                    "smallest size this day can show"]
    assert [r[1] for r in rows] == [p["cause"] for p in probs]
    assert [float(r[3]) for r in rows] == pytest.approx([p["probability"] for p in probs],
                                                        abs=1e-3)
    # the 3 K offset it found is above the size this day can show of one
    size = doc["detectability"]["sensor_bias"]["detectable_size"]
    assert 0.0 < size < 3.0 and rows[0][5] == f"{size:.3g} K"
