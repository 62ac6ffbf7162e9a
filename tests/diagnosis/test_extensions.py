"""The diagnosis' extensions (``softsensor/diagnosis/extensions.py``): each recovers the
parameter of data made by its own extended model, and finds (almost) nothing on a clean day."""

from __future__ import annotations

import numpy as np
import pytest
from diagnosis_problem import make_problem

from softsensor.diagnosis.day_windows import delagged_air
from softsensor.diagnosis.extensions import (
    AirSensorLag,
    LabTimeShift,
    SensorOffset,
    TransferDrift,
)
from softsensor.diagnosis.residuals import (
    LAB_SHIFTS_MIN,
    lab_stats,
)
from softsensor.model.dryer import parameter_index
from softsensor.plant.simulator import SimulatedDay


def test_sensor_offset_recovers_an_offset_on_the_right_channel(cfg, model, day):
    scans = day.scans.copy()
    scans["T_cyclone_out"] += 2.5
    p = make_problem(cfg, model, SimulatedDay(scans, day.labs, day.truth))
    f = SensorOffset().fit(p)
    assert f.channel == "T_cyclone_out"
    assert f.params["offset_K"] == pytest.approx(2.5, abs=0.05)
    # the whitened fit-part chi-square falls by far more than the calibration-error model
    # would charge for leaving the offset to its slow per-channel state
    assert p.chi2(p.baseline) - f.fit_chi2 > 10.0


def test_lab_time_shift_recovers_a_wrong_stamp(cfg, model, day):
    labs = day.labs.copy().sort_values("sample_time_ns")
    # labs report the model's own values, stamped 40 min late
    labs["sample_time_ns"] = labs.sample_time_ns + int(40 * 60e9)
    stamped = make_problem(cfg, model, SimulatedDay(day.scans, labs, day.truth))
    labs["moisture_out"] = stamped.baseline_labs(stamped.lab_points(shift_ns=-40 * 60e9))
    p = make_problem(cfg, model, SimulatedDay(day.scans, labs, day.truth))
    moved = np.abs(np.gradient(p.baseline.Y[:, 2])).max() > 1e-4
    assert moved
    ext = LabTimeShift()
    ext.min_chi2_drop = 0.0  # noise-free labs: any drop is real
    f = ext.fit(p)
    assert f.params["shift_min"] == pytest.approx(-40.0, abs=1.0)
    # the residual statistics see the same shift
    r = p.residuals(p.baseline)
    _, shifted = LabTimeShift.lab_chi2(p, LAB_SHIFTS_MIN)
    assert lab_stats(r.lab, p.windows, p.baseline.Y[:, 2], shifted).best_shift_min \
        == pytest.approx(-40.0, abs=2.0)


def _replace_outputs(day, p0, pred):
    """``day`` with its temperatures and labs moved from the baseline model to the prediction
    ``pred`` of an extended model (the day's own noise kept)."""
    w = p0.windows
    scans = day.scans.copy()
    k = np.clip((scans.index.to_numpy() - w.start_ns - 1) // int(600e9), 0, w.n_windows - 1)
    for c, name in enumerate(("T_dryer_out", "T_cyclone_out")):
        scans[name] = pred.Y[k, c] + (scans[name].to_numpy() - p0.baseline.Y[k, c])
    labs = day.labs.copy().sort_values("sample_time_ns")
    labs["moisture_out"] = labs.moisture_out.to_numpy() - p0.baseline.lab + pred.lab
    return SimulatedDay(scans, labs, day.truth)


def test_each_parametric_fit_recovers_its_own_model(cfg, model, day):
    """Data made by the extended model itself: each fit must recover its parameter, and on
    the clean day find (almost) nothing."""
    from softsensor.diagnosis.extensions import AmbientHeatLoss
    from softsensor.model.geometry import BETA_AMB, N_AUX

    p0 = make_problem(cfg, model, day)
    drift = TransferDrift()
    # the model itself run with mult_D and mult_h falling by 30 % over the day
    t_mid = (np.arange(p0.windows.n_windows) + 0.5) / p0.windows.n_windows
    theta = np.tile(p0.theta, (p0.windows.n_windows, 1))
    for name in ("mult_D", "mult_h"):
        theta[:, parameter_index(name)] *= 1.0 - 0.3 * t_mid
    p = make_problem(cfg, model, _replace_outputs(day, p0, p0.predict(theta=theta)))
    # fitted by least squares on whitened residuals: the slow calibration-error states take
    # a little of a drift (a few hundredths)
    assert drift.fit(p).params["loss_by_end"] == pytest.approx(0.3, abs=0.04)
    lag = AirSensorLag()
    w = p0.windows
    U, bins = delagged_air(w.segment, w.air_edges, 8.0 * 60.0)
    lagged = p0.predict(U, labs=p0.lab_points(U=U, bins=bins))
    p = make_problem(cfg, model, _replace_outputs(day, p0, lagged))
    assert lag.fit(p).params["tau_min"] == pytest.approx(8.0, abs=0.5)
    aux = np.zeros(N_AUX)
    aux[BETA_AMB] = 0.06
    amb = AmbientHeatLoss()
    p = make_problem(cfg, model, _replace_outputs(day, p0, p0.predict(aux=aux)))
    # the slow common calibration-error state takes a share of an ambient signature that
    # follows the slow ambient temperature
    assert amb.fit(p).params["beta_amb_per_K"] == pytest.approx(0.06, abs=0.015)
    clean = [lag.fit(p0).params["tau_min"], drift.fit(p0).params["loss_by_end"],
             amb.fit(p0).params["beta_amb_per_K"]]
    assert clean[0] < 2.0 and abs(clean[1]) < 0.05 and abs(clean[2]) < 0.01
