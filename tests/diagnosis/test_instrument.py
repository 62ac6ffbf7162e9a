"""One thermometer or a process change, and labs that settle the inlet (issue 48 items 3, 4).

On the clean 14 h day of the matched virtual plant (``clean_14h_day``, the config's
parameters, the two extensions that compete for an offset): both thermometers off together
is not an instrument fault; an offset on the loop's own thermometer ``T_dryer_out`` is named
on ``T_dryer_out``, not as the cyclone thermometer's. And an inlet-moisture verdict needs
labs that follow the outlet moisture its estimate implies.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.diagnose_day import LABS_FOLLOW, diagnose, labs_refute_inlet
from softsensor.diagnosis.extensions import LabTimeShift, SensorOffset
from softsensor.diagnosis.instrument import TOGETHER_SHARE, offset_contradiction
from softsensor.plant.simulator import SimulatedDay
from softsensor.presentation.verdicts import diagnosis_verdict
from softsensor.signals import OUTPUT_NAMES


@pytest.mark.parametrize(("means", "channel", "ruled_out"), [
    ((-0.77, -0.74), "T_dryer_out", "together"),      # issue 48's healthy day
    ((-0.77, -0.74), "T_cyclone_out", "together"),
    ((3.8, 0.1), "T_cyclone_out", None),              # which one: the whitened evidence's
    ((3.8, 0.1), "T_dryer_out", None),
    ((1.95, -1.96), "T_dryer_out", None),            # plant 8101's loop thermometer +4.5 K
    ((0.2, 2.9), "T_cyclone_out", None),
    ((2.0, 0.9), "T_dryer_out", None),                # the other below the share: allowed
])
def test_an_offset_is_ruled_out_where_the_raw_residuals_contradict_it(means, channel,
                                                                      ruled_out):
    why = offset_contradiction(None, channel, means=np.array(means))  # type: ignore[arg-type]
    if ruled_out is None:
        assert why is None
    else:
        assert why is not None and ruled_out in why
    assert TOGETHER_SHARE == 0.5


def _with_offsets(day, dryer: float, cyclone: float) -> SimulatedDay:
    scans = day.scans.copy()
    scans["T_dryer_out"] += dryer
    scans["T_cyclone_out"] += cyclone
    return SimulatedDay(scans, day.labs, day.truth)


def test_both_thermometers_off_together_is_not_an_instrument_fault(config, day):
    doc = diagnose(config, _with_offsets(day, 1.2, 1.1),
                   extensions=(SensorOffset(), LabTimeShift())).to_json()
    assert doc["cause"] != "sensor_bias", doc["probabilities"][:3]
    entry = next(r for r in doc["ranking"] if r["cause"] == "sensor_bias")
    assert entry["eligible"] is False and "together" in entry["contradicted"]
    assert doc["shapes"]["sensor_bias"]["log_bayes"] is None  # no alternative allowed


def test_the_loop_thermometers_offset_is_named_on_it_in_its_own_words(config, day):
    doc = diagnose(config, _with_offsets(day, 3.8, 0.0),
                   extensions=(SensorOffset(), LabTimeShift())).to_json()
    assert doc["cause"] == "sensor_bias" and doc["channel"] == "T_dryer_out"
    assert all(c["channel"] != "T_cyclone_out" for c in doc["probabilities"]
               if c["cause"] == "sensor_bias")
    assert "the one the outlet-temperature loop holds at its set point" in \
        diagnosis_verdict(doc)


def _score(lab_gain: float, labs: int = 8):
    fit = Fit(rmse={n: 1.0 for n in OUTPUT_NAMES},
              n={**{n: 10 for n in OUTPUT_NAMES}, "moisture_out": labs}, cost=0.1)
    from softsensor.diagnosis.verdict import Score

    return Score("inlet_moisture", None, 1, fit, fit, 0.3, fit, fit, 0.3,
                 {"T_dryer_out": 200.0, "T_cyclone_out": 200.0, "moisture_out": lab_gain},
                 400.0 + lab_gain, (), 800.0, 1e-9)


def test_an_inlet_verdict_needs_labs_that_follow_its_estimate():
    assert labs_refute_inlet(_score(LABS_FOLLOW + 5.0)) is None
    # labs that do not follow: flat while the temperatures moved (hundreds of nats there)
    for gain in (-20.0, 0.0, LABS_FOLLOW - 0.5):
        why = labs_refute_inlet(_score(gain))
        assert why is not None and "air flow or heat input" in why
    assert labs_refute_inlet(_score(30.0, labs=0)) is not None  # no labs: cannot settle
    sc = dataclasses.replace(_score(-20.0), contradicted=labs_refute_inlet(_score(-20.0)))
    assert not sc.eligible and ("ruled out by the residuals", sc.contradicted) in \
        sc.failed_checks()


def test_the_unexplained_verdict_points_at_flow_or_heat_when_the_labs_refuted_the_inlet():
    doc = {"cause": "unexplained", "ranking": [
        {"cause": "unexplained"},
        {"cause": "inlet_moisture", "contradicted": labs_refute_inlet(_score(-4.0))}]}
    assert "unmeasured change of air flow" in diagnosis_verdict(doc)
    doc["ranking"][1]["contradicted"] = None
    assert "air flow" not in diagnosis_verdict(doc)
