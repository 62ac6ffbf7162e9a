"""The peers inside the sensor and the band that holds (:mod:`softsensor.estimation.peer_blend`,
:mod:`softsensor.estimation.lab_regression`).

The band's conformal scale is tested on the pure :func:`advance` with a physics estimate
handed in; the weighting on virtual-plant days through the estimator: a model given badly
wrong parameters falls back to the held lab by the lab likelihood (and does not when the
weighting is off), a clean day stays on the physics.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from softsensor.estimate import Estimate
from softsensor.estimation.lab_regression import (
    LabRegression,
)
from softsensor.estimation.peer_blend import advance, check_state, fresh
from softsensor.estimation.publication import blended
from softsensor.estimation.settings import EstimatorSettings
from softsensor.messages import LabResult, Window
from softsensor.plantconfig import load_plant_config

CFG = load_plant_config()
T0 = 1_767_571_200 * 10**9
W = 600 * 10**9


def window(k: int, means: dict[str, float] | None = None) -> Window:
    return Window(start_ns=T0 + k * W, end_ns=T0 + (k + 1) * W, means=dict(means or {}),
                  n_scans=60, n_good={}, stale=False, reasons={})


def published(s: EstimatorSettings, reg, state, w: Window, labs, mo: float, sd: float):
    """One tick of the peers beside a physics estimate ``mo +- sd``: the new state and the
    published estimate's body (:func:`~softsensor.estimation.publication.blended`)."""
    state, blend, mixture = advance(s, reg, state, w, labs, (mo, sd))
    physics = Estimate(w.start_ns, w.end_ns, "ukf", mo, sd, None, None, None, None)
    return state, blended(physics, blend, mixture, s).to_body()


def run_band(s: EstimatorSettings, offsets: list[float], state=None):
    """Ticks with the physics at 0.10 +- 0.005 and a lab every third tick at 0.10 + offset;
    the band scale after each lab."""
    state = state or fresh(s, None)
    scales = []
    for i, off in enumerate(offsets):
        for k in range(3):
            t = 3 * i + k
            w = window(t)
            labs = ((LabResult(w.end_ns - W // 2, 0.10 + off, f"L{t}", w.end_ns),)
                    if k == 2 else ())
            state, body = published(s, None, state, w, labs, 0.10, 0.005)
        scales.append(body["band_scale"])
    return state, body, scales


BAND_ONLY = dataclasses.replace(EstimatorSettings(), peer_blend=False)


def test_the_band_widens_when_labs_fall_outside_and_narrows_when_they_sit_inside():
    state, body, wide = run_band(BAND_ONLY, [0.04] * 5)
    # each miss widens it by exp(0.95 * band_step): 1.33, 1.77, ...
    assert all(b > a for a, b in zip([1.0, *wide], wide, strict=False)), wide
    assert wide[-1] > 4.0  # 0.04 is now inside 1.96 x 4.2 x 0.005: no more widening
    assert body["moisture_out_std"] == pytest.approx(0.005 * wide[-1])
    assert body["moisture_out"] == 0.10  # the band only: the physics published as it is
    assert body["band_misses"] == [5, 5]
    _, body, narrow = run_band(BAND_ONLY, [0.0] * 60, state)  # exp(-0.015) per hit
    assert all(b < a for a, b in zip([wide[-1], *narrow], narrow, strict=False)), narrow
    assert narrow[-1] < 0.5 * wide[-1]


def test_the_band_scale_stays_within_its_bounds():
    _, _, wide = run_band(BAND_ONLY, [0.2] * 20)
    assert max(wide) == pytest.approx(BAND_ONLY.band_scale_max)
    _, _, narrow = run_band(BAND_ONLY, [0.0] * 400)
    assert min(narrow) == pytest.approx(BAND_ONLY.band_scale_min)


def test_without_the_features_the_physics_is_published_as_it_is():
    s = dataclasses.replace(EstimatorSettings(), peer_blend=False, band_conformal=False)
    _, body, scales = run_band(s, [0.04] * 3)
    assert scales == [1.0] * 3 and body["moisture_out_std"] == 0.005


def test_a_checkpointed_peer_state_is_checked():
    state, _, _ = run_band(EstimatorSettings(), [0.01, 0.0])
    check_state(state)
    for key, bad in (("log_w", [0.0, math.nan, 0.0]), ("log_scale", math.inf),
                     ("hold", [0.1]), ("log_w", [0.0, 1.0])):
        with pytest.raises(ValueError):
            check_state({**state, key: bad})


# --------------------------------------------------------------------------- virtual plant
@pytest.fixture(scope="module")
def clean_day():
    from softsensor.plant.simulator import simulate_day

    return simulate_day(CFG, 16, seed=21)


def run_plant(cfg, day, **settings):
    """The estimator over ``day`` (labs handed over at their log time): bodies and the truth
    at each tick."""
    from softsensor.estimation.settings import estimator_settings
    from softsensor.estimation.ukf import UkfEstimator
    from softsensor.windows.accumulator import windows_from_frame

    est = UkfEstimator(cfg, dataclasses.replace(estimator_settings(cfg), **settings))
    labs = sorted((LabResult(int(r.sample_time_ns), float(r.moisture_out), str(r.sample_id),
                             int(r.log_time_ns)) for r in day.labs.itertuples(index=False)),
                  key=lambda r: r.log_time_ns)
    t = day.truth.index.to_numpy()
    bodies, truth, j = [], [], 0
    for w in windows_from_frame(day.scans):
        while j < len(labs) and labs[j].log_time_ns <= w.end_ns:
            est.add_lab(labs[j])
            j += 1
        bodies.append(est.tick(w).to_body())
        truth.append(float(day.truth.moisture_out.to_numpy()[np.searchsorted(t, w.end_ns,
                                                                            "right") - 1]))
    return bodies, np.array(truth)


def rmse(bodies, truth, sel) -> float:
    mo = np.array([b["moisture_out"] for b in bodies])
    return float(np.sqrt(np.mean((mo - truth)[sel] ** 2)))


def test_a_misled_model_falls_back_to_the_held_lab_by_the_lab_likelihood(clean_day):
    """The model given a drying rate 0.4 times the plant's (mult_D): the lab results keep
    contradicting its physics, the held lab predicts them better, and the published estimate
    moves to it; with the weighting off it stays on the physics."""
    wrong = CFG.with_parameters({"mult_D": 0.4})
    blended, truth = run_plant(wrong, clean_day)
    physics, _ = run_plant(wrong, clean_day, peer_blend=False)
    ends = np.array([b["window_end_ns"] for b in blended])
    last = ends >= np.sort(clean_day.labs.log_time_ns.to_numpy())[-1]
    assert {b["source"] for b, k in zip(blended, last, strict=True) if k} == {"hold"}
    assert all(b["sources"]["physics"]["weight"] < 0.1 for b, k in zip(blended, last,
                                                                       strict=True) if k)
    assert rmse(blended, truth, last) < 0.5 * rmse(physics, truth, last)


def test_a_clean_day_stays_on_the_physics(clean_day):
    blended, truth = run_plant(CFG, clean_day)
    physics, _ = run_plant(CFG, clean_day, peer_blend=False, band_conformal=False)
    assert {b["source"] for b in blended} == {"physics"}
    assert min(b["sources"]["physics"]["weight"] for b in blended) > 0.8
    first = np.array([b["window_end_ns"] for b in blended]) >= clean_day.labs.log_time_ns.min()
    assert rmse(blended, truth, first) <= 1.05 * rmse(physics, truth, first)


def test_the_regression_source_is_the_regression_at_the_window_plus_the_last_labs_bias():
    """The regression peer with its lab-bias update (review: every other test handed in no
    regression): after a lab, its value at a later window is the regression there plus what
    the lab said the regression missed at the lab's window."""
    reg = LabRegression(signals=("T_air_in",), mean=np.array([480.0]), scale=np.array([10.0]),
                        coef=np.array([0.10, 0.01]), step_sd=0.004, hold_sd=0.006, n_labs=30)
    s = EstimatorSettings()
    state = fresh(s, reg)
    w_lab, w_next = window(0, {"T_air_in": 490.0}), window(1, {"T_air_in": 470.0})
    lab = LabResult(w_lab.end_ns - W // 2, 0.125, "L0", w_lab.end_ns)
    state, _ = published(s, reg, state, w_lab, (lab,), 0.11, 0.005)
    assert state["bias"] == pytest.approx(0.125 - reg.at_means(w_lab.means))  # 0.125 - 0.11
    state, body = published(s, reg, state, w_next, (), 0.11, 0.005)
    want = reg.at_means(w_next.means) + (0.125 - 0.11)  # 0.09 + 0.015
    assert body["sources"]["regression"]["moisture_out"] == pytest.approx(want, abs=1e-12)
    assert want == pytest.approx(0.105)


def _weights_after_labs(s: EstimatorSettings, n: int = 6) -> dict[str, float]:
    """The weights after ``n`` labs that sit on the held lab and 0.05 off the physics."""
    state = fresh(s, None)
    body = None
    for t in range(n):
        w = window(t)
        labs = (LabResult(w.end_ns - W // 2, 0.15, f"L{t}", w.end_ns),)
        state, body = published(s, None, state, w, labs, 0.10, 0.005)
    return {k: v["weight"] for k, v in body["sources"].items()}


def test_the_prior_weights_are_the_settings_and_the_evidence_can_be_tempered_away():
    """``peer_prior_hold`` places the prior; ``peer_evidence`` = 0 is a fixed stacking at
    it (the labs do not move the weights), 1 the full evidence (they do)."""
    from softsensor.estimation.peer_blend import prior_log_weights

    reg = LabRegression(("T_air_in",), np.zeros(1), np.ones(1), np.zeros(2), 0.01, 0.01, 9)
    s = dataclasses.replace(EstimatorSettings(), peer_prior_physics=0.6, peer_prior_hold=0.1)
    assert np.exp(prior_log_weights(s, reg)) == pytest.approx([0.6, 0.1, 0.3])
    assert np.exp(prior_log_weights(s, None))[:2] == pytest.approx([0.6, 0.4])
    even = dataclasses.replace(s, peer_prior_hold=None)
    assert np.exp(prior_log_weights(even, reg)) == pytest.approx([0.6, 0.2, 0.2])
    fixed = _weights_after_labs(dataclasses.replace(s, peer_evidence=0.0))
    assert fixed["physics"] == pytest.approx(0.6) and fixed["hold"] == pytest.approx(0.4)
    full = _weights_after_labs(dataclasses.replace(s, peer_evidence=1.0))
    assert full["hold"] > 0.9  # the labs sit on the hold, 10 sd off the physics


def test_a_prior_that_leaves_the_regression_less_than_nothing_is_refused():
    from softsensor.configfile import build_section
    from softsensor.errors import ConfigError

    with pytest.raises(ConfigError, match="peer_prior_hold must be at most"):
        build_section(EstimatorSettings, {"peer_prior_physics": 0.8, "peer_prior_hold": 0.3},
                      "estimator", "test.toml")
