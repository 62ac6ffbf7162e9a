"""The verdict (``softsensor/diagnosis/verdict.py``): cross-fitted predictions that never see
the data they score, the rules that name a cause, ``none`` or ``unexplained``."""

from __future__ import annotations

import numpy as np
import pytest
from diagnosis_problem import make_problem

from softsensor.calibration.cost import Fit
from softsensor.diagnosis.extensions import (
    LabTimeShift,
    SensorOffset,
    TransferDrift,
)
from softsensor.diagnosis.verdict import ALPHA, MIN_PENALISED, Score, verdict
from softsensor.plant.simulator import SimulatedDay


@pytest.mark.parametrize("extension", [SensorOffset(), LabTimeShift(), TransferDrift()],
                         ids=lambda e: e.cause)
def test_cross_fitted_predictions_never_see_the_data_they_score(cfg, model, day, extension):
    """Changing the measurements of one part must not move the cross-fitted prediction of
    that part (it comes from the fold fitted on the other part), and must move the fold
    fitted on it."""
    from softsensor.diagnosis.verdict import cross_fitted

    p = make_problem(cfg, model, day)
    k, t_split = p.split.k_fit, p.split.split_ns
    scans, labs = day.scans.copy(), day.labs.copy()
    early = scans.index.to_numpy() <= t_split
    scans.loc[early, "T_cyclone_out"] += 3.0
    scans.loc[early, "T_dryer_out"] -= 2.0
    early_lab = labs.sample_time_ns.to_numpy() < t_split
    labs.loc[early_lab, "moisture_out"] += 0.02
    q = make_problem(cfg, model, SimulatedDay(scans, labs, day.truth))
    assert q.split.k_fit == k
    fp, bp = extension.fit_both(p)
    fq, bq = extension.fit_both(q)
    cp = cross_fitted(p, fp.prediction, bp.prediction)
    cq = cross_fitted(q, fq.prediction, bq.prediction)
    np.testing.assert_allclose(cq.Y[:k], cp.Y[:k], rtol=0, atol=1e-9)
    held_early = p.split.lab_fit
    np.testing.assert_allclose(cq.lab[held_early], cp.lab[held_early], rtol=0, atol=1e-12)
    if extension.cause != "lab_delay":  # a lab shift below its gate stays at zero on both
        # the first fold was fitted on the changed part: its prediction of the rest moves
        assert not np.allclose(fq.prediction.Y[k:], fp.prediction.Y[k:], rtol=0, atol=1e-6)


def _score(cause, penalised, gain=0.1, p=1e-6, worse=(), channel=None):
    h = Fit(rmse={"T_dryer_out": 1.0, "T_cyclone_out": 1.0, "moisture_out": 0.01},
            n={"T_dryer_out": 10, "T_cyclone_out": 10, "moisture_out": 3}, cost=0.1)
    return Score(cause, channel, 1, h, h, gain, h, h, gain, {"T_dryer_out": penalised + 1,
                                                 "T_cyclone_out": 0.0, "moisture_out": 0.0},
                 penalised, tuple(worse), 30.0, p)


def test_verdict_names_the_best_eligible_extension():
    v = verdict([_score("fouling_drift", 50.0), _score("inlet_moisture", 80.0, p=0.01),
                 _score("ambient_heat_loss", 20.0), _score("sensor_bias", 90.0,
                                                           worse=("T_dryer_out",))], None)
    assert v.cause == "fouling_drift"
    assert [c for c, _, _ in v.ranking][:3] == ["fouling_drift", "ambient_heat_loss", "none"]
    scores = dict((c, s) for c, s, _ in v.ranking)
    assert scores["fouling_drift"] > 0.99 and scores["inlet_moisture"] == 0.0
    assert sum(s for _, s, _ in v.ranking) == pytest.approx(1.0)


def test_verdict_none_or_unexplained_without_an_eligible_extension():
    weak = [_score("lab_delay", 3.0, p=0.5), _score("input_lag", MIN_PENALISED - 0.5)]
    assert verdict(weak, None).cause == "none"
    assert verdict(weak, "T_dryer_out residuals are 3.0 times ...").cause == "unexplained"
    assert not _score("x", 50.0, p=2 * ALPHA).eligible
    assert "not significant" in _score("x", 50.0, p=2 * ALPHA).why_not()
    assert not weak[1].eligible and "below" in weak[1].why_not()
    assert _score("x", MIN_PENALISED).eligible and _score("x", MIN_PENALISED).why_not() is None
    # the fix of a cause must lower eq. 4 on data it was not fitted on
    assert not _score("x", 50.0, gain=-0.01).eligible
    assert "gain under eq. 4" in _score("x", 50.0, gain=-0.01).why_not()
    assert "worse" in _score("x", 50.0, worse=("moisture_out",)).why_not()


def test_unexplained_when_the_residuals_exceed_what_the_calibration_error_allows(cfg, model,
                                                                                 day):
    """A 1.5 K oscillation of 2 h period on one sensor is faster than any calibration error
    and than every extension tried here: ``unexplained``, naming the channel; the clean day
    is ``none``."""
    from softsensor.diagnosis.diagnose_day import diagnose
    from softsensor.diagnosis.verdict import structured

    scans = day.scans.copy()
    t_h = (scans.index.to_numpy() - scans.index[0]) / 3.6e12
    scans["T_cyclone_out"] += 1.5 * np.sin(2 * np.pi * t_h / 2.0)
    d = diagnose(cfg, SimulatedDay(scans, day.labs, day.truth), extensions=(LabTimeShift(),))
    assert d.cause == "unexplained"
    assert "T_cyclone_out" in d.verdict.structure and "T_dryer_out" not in d.verdict.structure
    assert structured(make_problem(cfg, model, day)) is None
