"""The open-loop estimator: the calibrated model fed measured inputs and the nominal inlet
moisture, checked against the model itself, and its lab handling and restart."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from softsensor.errors import EstimationError, IngestError
from softsensor.estimation.interface import LabResult
from softsensor.estimation.open_loop_estimator import OpenLoopEstimator
from softsensor.model import DryerModel
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config
from softsensor.signals import INPUT_NAMES
from softsensor.windows.accumulator import windows_from_frame

CFG = load_plant_config()


@pytest.fixture(scope="module")
def day():
    d = simulate_day(CFG, 6, seed=3, effect="inlet_moisture", magnitude=0.2)
    # the day's first and last scans fall in windows of their own (stale)
    return d, [w for w in windows_from_frame(d.scans) if not w.stale]


def test_outputs_are_the_model_run_on_window_means_with_nominal_inlet_moisture(day):
    d, windows = day
    est = OpenLoopEstimator(CFG)
    bodies = [est.tick(w).to_body() for w in windows]
    U = np.array([[w.means[n] for n in INPUT_NAMES[:-1]] + [CFG.nominal.moisture_in]
                  for w in windows])
    Y, _ = DryerModel(CFG).simulate(U)
    got = np.array([[b["T_dryer_out_model"], b["T_cyclone_out_model"], b["moisture_out"]]
                    for b in bodies])
    np.testing.assert_allclose(got, Y, rtol=0, atol=1e-9)
    assert all(b["moisture_in"] == CFG.nominal.moisture_in for b in bodies)
    # and it misses the inlet-moisture disturbance that the filter is for
    truth = d.truth.moisture_out.reindex([w.end_ns for w in windows], method="ffill")
    assert np.sqrt(np.mean((Y[:, 2] - truth.to_numpy()) ** 2)) > 0.02


def test_reported_std_is_the_configured_prior(day):
    _, windows = day
    cfg = dataclasses.replace(CFG, extra={"estimator": {"openloop_moisture_out_std": 0.07,
                                                        "openloop_moisture_in_std": 0.2}})
    body = OpenLoopEstimator(cfg).tick(windows[0]).to_body()
    assert body["moisture_out_std"] == 0.07 and body["moisture_in_std"] == 0.2
    assert "fixed prior" in body["detail"]


def test_labs_leave_the_estimate_alone_and_report_the_residual(day):
    d, windows = day
    with_labs, without = OpenLoopEstimator(CFG), OpenLoopEstimator(CFG)
    a = [without.tick(w).to_body() for w in windows[:20]]
    b = [with_labs.tick(w).to_body() for w in windows[:10]]
    lab = LabResult(windows[4].end_ns - 60 * 10**9, 0.123, "S1", windows[9].end_ns)
    assert with_labs.add_lab(lab) is None
    assert "duplicate" in with_labs.add_lab(lab)
    with pytest.raises(IngestError, match="outside the plausible range"):  # the contract's
        dataclasses.replace(lab, sample_id="S2", moisture_out=2.5)
    b += [with_labs.tick(w).to_body() for w in windows[10:20]]
    assert b[10]["lab_residual"] == {"S1": pytest.approx(0.123 - a[4]["moisture_out"])}
    assert not b[10]["lab_updated"]
    strip = [{k: v for k, v in x.items() if k != "lab_residual"} for x in b]
    assert strip == [{k: v for k, v in x.items() if k != "lab_residual"} for x in a]


def test_stale_window_and_restart(day):
    _, windows = day
    straight = OpenLoopEstimator(CFG)
    ref = [straight.tick(w).to_body() for w in windows[:30]]
    first = OpenLoopEstimator(CFG)
    for w in windows[:15]:
        first.tick(w)
    second = OpenLoopEstimator(CFG)
    second.restore(json.loads(json.dumps(first.checkpoint(), allow_nan=False)))
    assert [second.tick(w).to_body() for w in windows[15:30]] == ref[15:]
    stale = dataclasses.replace(windows[30], stale=True)
    assert second.tick(stale).to_body()["status"] == "stale"
    with pytest.raises(EstimationError, match="not after the last tick"):
        second.tick(windows[3])
    with pytest.raises(EstimationError, match="kind 'ukf'"):
        second.restore({"kind": "ukf", "version": 1})
