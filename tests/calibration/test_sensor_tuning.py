"""What the sensor learns of its plant from the history (issue 47 items 2 and 3,
:mod:`softsensor.calibration.sensor_tuning`).

The blend's fit and the noise search are tested on days whose outcome is known by
construction (recorded ticks of a physics that is off by a set amount, or a lab score peaked
at a set noise), so the test takes milliseconds and asserts what the learning must find; the
end-to-end run through the filter, the PARAMS.toml round trip and the estimator reading the
learned values are tested on a short virtual-plant history.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from softsensor.calibration.sensor_score import DayRun
from softsensor.calibration.sensor_tuning import (
    NOISE_KEYS,
    blend_errors,
    fit_blend,
    fit_noise,
)
from softsensor.estimation.settings import EstimatorSettings
from softsensor.messages import LabResult, Window

T0 = 1_767_571_200 * 10**9
W = 600 * 10**9
SHIPPED = dataclasses.replace(EstimatorSettings(), peer_blend=True, band_conformal=False)


def _day(seed: int, physics_offset: float, n: int = 288, every: int = 6) -> DayRun:
    """A day of ``n`` ticks: a true outlet moisture that wanders, the physics publishing it
    plus ``physics_offset`` (sd 0.004), a lab result every ``every`` ticks (lab noise
    0.003)."""
    rng = np.random.default_rng(seed)
    truth = 0.10 + 0.01 * np.sin(np.arange(n) / 40.0 + seed) + np.cumsum(
        rng.normal(0, 0.0008, n))
    windows = [Window(T0 + k * W, T0 + (k + 1) * W, {}, 60, {}, False, {}) for k in range(n)]
    physics = [(float(truth[k] + physics_offset), 0.004) for k in range(n)]
    ks = np.arange(3, n, every)
    labs = [LabResult(int(windows[k].end_ns - W // 2), float(truth[k] + rng.normal(0, 0.003)),
                      f"L{seed}-{k}", int(windows[k].end_ns)) for k in ks]
    return DayRun(windows, physics, labs, ks, [None] * len(labs), [None] * len(labs))


def test_the_blend_is_replayed_from_the_recorded_ticks():
    """With the physics' prior at all but nothing and no evidence, the blend is the
    physics: its errors are the labs' distance from it."""
    day = _day(1, 0.02)
    s = dataclasses.replace(SHIPPED, peer_prior_physics=0.999999, peer_evidence=0.0)
    e = blend_errors(day, s)
    assert e.size == len(day.labs) and abs(np.mean(e) + 0.02) < 0.002


def test_a_physics_that_is_off_loses_its_weight_to_the_hold_out_of_fold():
    days = [_day(s, 0.03) for s in range(4)]
    tuned, check, verdict = fit_blend(days, SHIPPED)
    assert verdict.startswith("learned")
    # the shipped evidence already leans to the hold; the learned prior does better still
    assert check["rmse_learned_held_out"] < check["rmse_shipped"] < 0.03
    assert tuned.peer_prior_physics < SHIPPED.peer_prior_physics


def test_a_physics_that_holds_keeps_its_weight():
    days = [_day(s, 0.0) for s in range(4)]
    tuned, check, _ = fit_blend(days, SHIPPED)
    # the physics publishes the truth, the labs carry 0.003 of noise: held out, the learned
    # blend stays at that floor (0.0029), short of a blend leaning on the hold (0.0040)
    assert check["rmse_learned_held_out"] <= check["rmse_shipped"] * 1.05
    assert check["rmse_learned_held_out"] < 0.0035


def _score_days(truth: dict[str, float], width: float = 0.5):
    """A stand-in for filtering the tuning days: 200 lab log densities peaked at the noise
    ``truth`` (in log space, ``width`` wide), so the search's answer is known."""
    calls = []

    def run_days(s: EstimatorSettings) -> list[DayRun]:
        calls.append(s)
        miss = sum((math.log(getattr(s, k) / v) / width) ** 2 for k, v in truth.items())
        run = _day(0, 0.0)
        return [dataclasses.replace(run, log_density=[-0.5 * miss] * 200)]

    return run_days, calls


def test_the_noise_search_finds_a_plant_whose_noise_is_four_times_the_shipped():
    s = EstimatorSettings()
    truth = {"moisture_in_walk": 4 * s.moisture_in_walk,
             "inlet_gain_walk": s.inlet_gain_walk / 4,
             "transient_fraction": s.transient_fraction}
    run_days, calls = _score_days(truth)
    learned, se, _ = fit_noise(run_days, s)
    for k, v in truth.items():
        assert 1 / 1.5 <= getattr(learned, k) / v <= 1.5, k
    assert set(se) == set(NOISE_KEYS) and all(v > 1 for v in se.values())
    assert len(calls) <= 1 + 2 * len(NOISE_KEYS)


def test_the_shipped_noise_stays_when_the_plant_is_the_shipped():
    s = EstimatorSettings()
    run_days, _ = _score_days({k: getattr(s, k) for k in NOISE_KEYS})
    learned, _, _ = fit_noise(run_days, s)
    assert all(getattr(learned, k) == getattr(s, k) for k in NOISE_KEYS)


def _params_with_sensor(tmp_path, values, name="p.toml"):
    from softsensor.calibration.params_file import params_document, write_params
    from softsensor.plantconfig import PARAMETER_NAMES, load_plant_config

    base = load_plant_config()
    doc = params_document(base, dict(zip(PARAMETER_NAMES, base.parameter_vector().tolist(),
                                         strict=True)), {"objective": 0.0})
    doc["sensor"] = {"days": 4, "labs": 40, "values": values, "shipped": {}, "deployed": {}}
    path = tmp_path / name
    write_params(path, doc)
    return base, path


def test_the_learned_values_reach_the_estimator_and_its_fingerprint(tmp_path):
    """PARAMS.toml's ``[sensor].values`` replace the shipped ``[estimator]`` defaults; a key
    the plant config sets itself wins; a change of them is a change of calibration for a
    checkpoint (``made_with``)."""
    import dataclasses as dc

    from softsensor.errors import ConfigError
    from softsensor.estimation.settings import estimator_settings
    from softsensor.plantconfig import load_parameters, made_with

    base, path = _params_with_sensor(tmp_path, {"moisture_in_walk": 0.03,
                                                "peer_prior_physics": 0.4,
                                                "peer_prior_hold": 0.1, "peer_evidence": 0.5})
    cfg = load_parameters(path, base)
    s = estimator_settings(cfg)
    assert (s.moisture_in_walk, s.peer_prior_physics, s.peer_prior_hold, s.peer_evidence) == (
        0.03, 0.4, 0.1, 0.5)
    own = dc.replace(base, extra={**base.extra, "estimator": {"moisture_in_walk": 0.02}})
    assert estimator_settings(load_parameters(path, own)).moisture_in_walk == 0.02
    _, other = _params_with_sensor(tmp_path, {"moisture_in_walk": 0.01}, "q.toml")
    a, b = made_with(cfg), made_with(load_parameters(other, base))
    assert a["sensor"] != b["sensor"] and a["parameters"] == b["parameters"]
    _, bad = _params_with_sensor(tmp_path, {"moisture_in_walk": -1.0}, "r.toml")
    with pytest.raises(ConfigError, match="estimator.moisture_in_walk"):
        estimator_settings(load_parameters(bad, base))


@pytest.mark.parametrize("part", ["parameters", "structure", "discrepancy", "model_error",
                                  "regression", "sensor"])
def test_every_part_of_a_calibration_is_in_the_checkpoints_fingerprint(part):
    """A checkpoint made under one calibration is not continued under another as if nothing
    had changed (issue 47: a fingerprint cut to the parameters alone went unnoticed): each
    part, changed alone, changes its own digest and no other."""
    from softsensor.plantconfig import load_plant_config, made_with, with_table

    base = load_plant_config()
    if part == "parameters":
        other = base.with_parameters(base.parameter_vector() * 1.1)
    elif part == "structure":
        other = base.with_keys({"fiber.critical_moisture": base.fiber.critical_moisture * 0.9})
    else:
        other = with_table(base, part, {"changed": 1})
    a, b = made_with(base), made_with(other)
    assert [k for k in a if a[k] != b[k]] == [part]
    assert set(a) == {"parameters", "structure", "discrepancy", "model_error", "regression",
                      "sensor"}


def test_the_sensor_score_is_the_filters(tmp_path):
    """The prequential lab score runs the filter: the same day scores differently when the
    filter's noise differs, and every lab handed over is scored once."""
    from softsensor.calibration.dataset import segment_from_day
    from softsensor.calibration.sensor_score import filter_day
    from softsensor.estimation.settings import estimator_settings
    from softsensor.plant.simulator import simulate_day
    from softsensor.plantconfig import load_plant_config

    base = load_plant_config()
    seg = segment_from_day(simulate_day(base, 6.0, 11, effect="inlet_moisture",
                                        magnitude=0.15), base, source="day")
    s = dataclasses.replace(estimator_settings(base), peer_blend=False, band_conformal=False)
    a = filter_day(base, seg, s)
    b = filter_day(base, seg, dataclasses.replace(s, moisture_in_walk=s.moisture_in_walk * 9))
    assert len(a.labs) == len(a.log_density) > 0
    assert [x is None for x in a.log_density] == [x is None for x in b.log_density]
    scored = [(x, y) for x, y in zip(a.log_density, b.log_density, strict=True)
              if x is not None]
    assert scored and any(abs(x - y) > 1e-6 for x, y in scored)
