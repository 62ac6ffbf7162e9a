"""A probability for every cause and "cannot tell" (issue 33 items 2 and 3): the rules on
made-up scores and signatures (milliseconds). The probabilities of real diagnoses are
checked where those run already: the independent-plant days of
``tests/diagnosis/test_diagnose_history.py`` and the report page of
``tests/presentation/test_diagnosis_report.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.detectability import Signature, collinearity
from softsensor.diagnosis.posterior import (
    COLLINEAR,
    INELIGIBLE_PENALTY,
    cannot_tell,
    fit_temperature,
    posterior,
    softmax,
)
from softsensor.diagnosis.verdict import MIN_PENALISED, Score, verdict


def _score(cause, penalised, gain=0.1, worse=(), channel=None):
    h = Fit(rmse={"T_dryer_out": 1.0, "T_cyclone_out": 1.0, "moisture_out": 0.01},
            n={"T_dryer_out": 10, "T_cyclone_out": 10, "moisture_out": 3}, cost=0.1)
    return Score(cause, channel, 1, h, h, gain, h, h, gain,
                 {"T_dryer_out": penalised + 1, "T_cyclone_out": 0.0, "moisture_out": 0.0},
                 penalised, tuple(worse), 30.0, 1e-6)


#: (scores, structure margin s, the verdict's cause)
CASES = {
    "winner": ([_score("fouling_drift", 40.0), _score("ambient_heat_loss", 25.0),
                _score("sensor_bias", 90.0, worse=("moisture_out",), channel="T_dryer_out")],
               -5.0, "fouling_drift"),
    "winner on a structured day": ([_score("inlet_moisture", 300.0),
                                    _score("lab_delay", 2.0)], 280.0, "inlet_moisture"),
    "clean": ([_score("lab_delay", 4.0), _score("input_lag", MIN_PENALISED - 0.5),
               _score("fouling_drift", 60.0, gain=0.01)], -30.0, "none"),
    "unexplained": ([_score("lab_delay", 4.0), _score("input_lag", 9.0)], 12.0,
                    "unexplained"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_probabilities_sum_to_one_and_the_verdicts_cause_is_the_most_probable(case):
    scores, s, cause = CASES[case]
    v = verdict(scores, "structured" if s > 0 else None)
    assert v.cause == cause
    for t in (0.3, 1.0, 5.0):
        cands = posterior(v, scores, ["inlet_moisture"] if case == "clean" else [], s, t)
        assert sum(c.probability for c in cands) == pytest.approx(1.0, abs=1e-12)
        assert cands[0].cause == cause
        assert [c.probability for c in cands] == sorted((c.probability for c in cands),
                                                        reverse=True)
        names = {c.cause for c in cands}
        assert {"none", "unexplained"} <= names and {sc.cause for sc in scores} <= names


def test_evidence_follows_the_gains_and_charges_every_failed_check():
    scores, s, _ = CASES["winner"]
    v = verdict(scores, None)
    L = {c.cause: c.log_evidence for c in posterior(v, scores, [], s)}
    assert L["fouling_drift"] == pytest.approx(40.0 - MIN_PENALISED)
    assert L["ambient_heat_loss"] == pytest.approx(25.0 - MIN_PENALISED)
    # an extension that makes a channel worse stays below the unextended model however
    # much it gains
    assert L["sensor_bias"] == pytest.approx(-INELIGIBLE_PENALTY)
    assert L["none"] == 0.0 and L["unexplained"] == pytest.approx(s)
    # a clean day: the none candidate holds most of the probability
    scores, s, _ = CASES["clean"]
    cands = posterior(verdict(scores, None), scores, [], s, 1.0)
    assert cands[0].cause == "none" and cands[0].probability > 0.8
    # a clearly structured day without a signature: none pays for the structure
    scores, s, _ = CASES["unexplained"]
    L = {c.cause: c.log_evidence for c in posterior(verdict(scores, "x"), scores, [], s)}
    assert L["none"] == pytest.approx(-s) and L["unexplained"] == 0.0


def _sig(cause, vector):
    return Signature(cause, None, 1.0, "u", 1, np.asarray(vector, float))


def test_cannot_tell_names_both_only_when_close_and_collinear():
    scores = [_score("ambient_heat_loss", 30.0), _score("fouling_drift", 29.0)]
    v = verdict(scores, None)
    cands = posterior(v, scores, [], -5.0, 1.0)
    same = {"ambient_heat_loss": _sig("ambient_heat_loss", [1.0, 2.0, 3.0]),
            "fouling_drift": _sig("fouling_drift", [-1.1, -2.0, -3.1])}
    both = cannot_tell(cands, same)
    assert both is not None
    assert [c["cause"] for c in both["causes"]] == ["ambient_heat_loss", "fouling_drift"]
    assert both["collinearity"] >= COLLINEAR
    # signatures that differ on this day: the data tell them apart
    apart = dict(same, fouling_drift=_sig("fouling_drift", [3.0, 0.0, -1.0]))
    assert collinearity(apart["ambient_heat_loss"], apart["fouling_drift"]) < COLLINEAR
    assert cannot_tell(cands, apart) is None
    # the same signatures, but one cause far more probable: no doubt to report
    far = [_score("ambient_heat_loss", 60.0), _score("fouling_drift", 29.0)]
    assert cannot_tell(posterior(verdict(far, None), far, [], -5.0, 1.0), same) is None
    # an empty signature (the cause leaves nothing on this day) is collinear with nothing
    assert collinearity(same["fouling_drift"], _sig("lab_delay", [0.0, 0.0, 0.0])) == 0.0


def test_detectable_size_is_where_the_signature_reaches_the_verdicts_threshold():
    sig = _sig("sensor_bias", [3.0, 4.0])  # |d| = 5 at size 1
    x = sig.detectable_size
    assert 0.5 * (5.0 * x) ** 2 - 1 == pytest.approx(MIN_PENALISED)
    assert _sig("lab_delay", [0.0, 0.0]).detectable_size == math.inf


def test_the_temperature_is_fitted_to_the_days_it_is_given():
    rng = np.random.default_rng(3)
    days = []
    for _ in range(400):
        L = rng.normal(0.0, 4.0, size=5)
        days.append((L, int(rng.choice(5, p=softmax(L, 2.5)))))
    assert fit_temperature(days) == pytest.approx(2.5, rel=0.2)
