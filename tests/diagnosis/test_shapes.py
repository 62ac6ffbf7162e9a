"""The causes' shapes on the residuals (:mod:`softsensor.diagnosis.shapes`): the exact evidence
of a linear-Gaussian shape, the whitening it relies on, and a shape found where it was put.
Each cause named by its shape on an independent-plant day against the plant's normal:
``test_diagnose_history.py``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from diagnosis_problem import make_problem
from scipy.stats import multivariate_normal

from softsensor.diagnosis.posterior import SHAPE_CHARGE, shape_evidence
from softsensor.diagnosis.problem import Prediction
from softsensor.diagnosis.shapes import OffsetShape, ShapeFit, linear_evidence, whitened_shape
from softsensor.plant.simulator import SimulatedDay


def _brute_force(v, W, sd, box):
    """``log B`` by integrating the likelihood ratio over the prior on a grid of ``box``
    (per size ``(lo, hi)``; a size cut to one sign has 0 as a bound, its prior doubled)."""
    axes = [np.linspace(lo, hi, 601) for lo, hi in box]
    X, Y = np.meshgrid(*axes)
    P = np.stack([X.ravel(), Y.ravel()])
    ll = -0.5 * np.sum((v[:, None] - W @ P) ** 2, axis=0) + 0.5 * float(v @ v)
    prior = multivariate_normal([0.0, 0.0], np.diag(np.square(sd))).pdf(P.T)
    cut = 2.0 ** sum(lo == 0.0 or hi == 0.0 for lo, hi in box)
    cell = float(np.prod([a[1] - a[0] for a in axes]))
    return math.log(float(np.sum(np.exp(ll) * prior * cut)) * cell)


@pytest.mark.parametrize("signs", [(0, 0), (-1, -1), (-1, 0)])
def test_the_evidence_is_the_integral_of_the_likelihood_over_the_prior(signs):
    rng = np.random.default_rng(7)
    W = rng.normal(size=(40, 2))
    v = W @ np.array([-1.0, -0.5]) + rng.normal(size=40)
    sd = np.array([3.0, 3.0])
    lb, mean = linear_evidence(v, W, sd, np.array(signs))
    box = [(-15.0, 0.0) if s < 0 else (-15.0, 15.0) for s in signs]
    assert lb == pytest.approx(_brute_force(v, W, sd, box), abs=0.01)
    assert mean == pytest.approx(np.linalg.lstsq(W, v, rcond=None)[0], abs=0.05)


@pytest.mark.parametrize("moved", ["both", "temperatures", "labs"])
def test_a_shape_is_whitened_as_the_residuals_are(cfg, model, day, moved):
    """The evidence rests on the normal's whitening being linear: a change ``g`` of the
    prediction moves the baseline's whitened residuals by exactly the whitened ``g``, also
    where ``g`` leaves the temperatures or the labs alone (whitened_shape skips their
    filter)."""
    p = make_problem(cfg, model, day)
    K, L = p.windows.n_windows, p.windows.lab_value.size
    g_T = np.zeros((K, 2))
    if moved != "labs":
        g_T[K // 3:, 1] = 0.7
    g_lab = np.linspace(0.0, 0.004, L) if moved != "temperatures" else np.zeros(L)
    base = np.concatenate(p.whitened(p.baseline, "all"))
    Y = p.baseline.Y.copy()
    Y[:, :2] -= g_T  # a prediction lower by g leaves residuals higher by g
    moved = np.concatenate(p.whitened(Prediction(Y, p.baseline.lab - g_lab), "all"))
    assert moved - base == pytest.approx(whitened_shape(p, g_T, g_lab), abs=1e-9)


def test_an_offset_on_one_thermometer_is_found_on_it_and_not_on_a_clean_day(cfg, model, day):
    clean = OffsetShape().fit(make_problem(cfg, model, day))
    scans = day.scans.copy()
    scans["T_dryer_out"] += 6.0
    fit = OffsetShape().fit(make_problem(cfg, model, SimulatedDay(scans, day.labs, day.truth)))
    assert fit.channel == "T_dryer_out"
    assert fit.params["onset_h"] == 0.0
    assert fit.params["offset_K"] == pytest.approx(6.0, abs=0.3)
    assert shape_evidence(fit) > 0.0, fit
    assert shape_evidence(clean) < 0.0, clean


def test_a_shape_pays_for_what_it_leaves_structured():
    fit = ShapeFit("sensor_bias", "T_dryer_out", 40.0, -3.0, {}, "")
    assert shape_evidence(fit) == pytest.approx(40.0 - SHAPE_CHARGE)
    left = ShapeFit("sensor_bias", "T_dryer_out", 40.0, 25.0, {}, "")
    assert shape_evidence(left) == pytest.approx(40.0 - SHAPE_CHARGE - 25.0)
    gone = ShapeFit.from_json(ShapeFit("ambient_heat_loss", None, -math.inf, math.inf, {},
                                       "not applicable").to_json())
    assert shape_evidence(gone) == -math.inf
