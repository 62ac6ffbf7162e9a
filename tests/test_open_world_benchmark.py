"""``benchmarks/open_world.py``: its plan, scoring and summaries (fast), and a ``--quick`` run
(slow: simulates, calibrates, estimates and diagnoses, a few minutes on two cores)."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from softsensor.plant.effects import EFFECTS

PATH = Path(__file__).resolve().parent.parent / "benchmarks" / "open_world.py"


@pytest.fixture(scope="module")
def ow() -> ModuleType:
    spec = importlib.util.spec_from_file_location("open_world_benchmark", PATH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_stratified_draws_one_magnitude_per_stratum(ow):
    rng = np.random.default_rng(0)
    mags = sorted(ow.stratified(0.2, 0.6, 4, rng))
    for i, m in enumerate(mags):
        assert 0.2 + 0.1 * i <= m <= 0.2 + 0.1 * (i + 1)


def test_plan_has_distinct_day_seeds_every_cause_and_detectable_magnitudes(ow):
    book = ow.SeedBook(12345)
    plan = ow.make_plan("independent", book, 3, 2, 2)
    matched = ow.make_plan("model", book, 1, 1, 1)
    seeds = [d.seed for p in (plan, matched) for d in (
        [x for pair in p.calibration for x in pair] + [x for ds in p.estimator for x in ds]
        + p.broken + p.diagnosis)]
    assert len(seeds) == len(set(seeds))
    assert len(set(plan.plant_seeds)) == 3 and matched.plant_seeds == [None]
    assert [d.effect for d in plan.diagnosis].count("none") == 2
    for c, spec in EFFECTS.items():
        mags = [d.magnitude for d in plan.diagnosis if d.effect == c]
        assert len(mags) == 2 and all(spec.detectable[0] <= m <= spec.detectable[1]
                                      for m in mags)
        # the two days of a cause sit on different plants
        assert len({d.plant for d in plan.diagnosis if d.effect == c}) == 2
    lo, hi = EFFECTS["inlet_moisture"].detectable
    assert all(lo <= ds[1].magnitude <= hi and ds[1].effect == "inlet_moisture"
               for ds in plan.estimator)
    again = ow.make_plan("independent", ow.SeedBook(12345), 3, 2, 2)
    assert again.as_dict() == plan.as_dict()


def _track(n: int = 10, err: float = 0.001, sd: float = 0.002) -> dict[str, np.ndarray]:
    end = np.arange(1, n + 1, dtype=np.int64) * 600 * 10**9
    truth = np.full(n, 0.1)
    hold = np.full(n, np.nan)
    hold[3:] = 0.1 + 2 * err
    return {"end": end, "mo": truth + err, "mo_sd": np.full(n, sd), "mi": np.full(n, 1.0),
            "mi_sd": np.full(n, 0.01), "status": np.array(["ok"] * (n - 1) + ["degraded"]),
            "fallback": np.zeros(n, bool), "failed": np.zeros(n, bool), "truth_mo": truth,
            "truth_mi": np.full(n, 1.05), "hold": hold,
            "first_lab_ns": np.array([end[3]]), "labs_refused": np.array([0])}


def test_score_estimator_against_hand_numbers(ow):
    s = ow.score_estimator(ow._with_after(_track()))
    assert s["moisture_out_rmse"] == pytest.approx(0.001)
    assert s["hold_last_lab_rmse"] == pytest.approx(0.002)
    assert s["ratio_to_hold"] == pytest.approx(0.5)
    assert s["coverage95_moisture_out"] == 1.0
    assert s["moisture_in_rmse_after_first_lab"] == pytest.approx(0.05)
    assert s["coverage95_moisture_in"] == 0.0
    assert s["degraded_share"] == pytest.approx(0.1)
    pooled = ow.score_estimator(ow.pool([ow._with_after(_track()),
                                         ow._with_after(_track(err=0.003, sd=0.001))]))
    assert pooled["moisture_out_rmse"] == pytest.approx(math.sqrt((0.001**2 + 0.003**2) / 2))
    assert pooled["coverage95_moisture_out"] == pytest.approx(0.5)


def test_estimator_summary_checks(ow):
    day = ow.score_estimator(ow._with_after(_track()))
    part = {"days": [{"effect": "none", **day}], "broken_model": [{"degraded_share": 0.9}],
            "pooled": day}
    s = ow.estimator_summary(part)
    assert s["checks"]["pooled_rmse"] and s["checks"]["ratio"] and s["checks"]["range"]
    assert s["checks"]["broken_degraded"]
    assert not s["checks"]["degraded_clean"]          # 10 % of the ticks degraded
    assert not s["checks"]["coverage"]                # 100 %: bands too wide
    assert not s["pass"]


def test_diagnosis_summary_counts_false_alarms_and_gains(ow):
    days = [
        {"seed": 1, "cause": "none", "named": "none", "gain": 0.0, "right": True},
        {"seed": 2, "cause": "none", "named": "sensor_bias", "gain": 0.1, "right": False},
        {"seed": 3, "cause": "lab_delay", "named": "lab_delay", "gain": -0.01, "right": True},
        {"seed": 4, "cause": "unexplained", "named": "unexplained", "gain": 0.0,
         "right": True},
        {"seed": 5, "cause": "input_lag", "error": "boom", "right": False},
    ]
    s = ow.diagnosis_summary(days)
    assert s["right_share"] == pytest.approx(3 / 5)
    assert s["false_alarms"] == 1 and s["failed_days"] == 1
    assert [b["seed"] for b in s["named_without_positive_gain"]] == [3]
    assert s["per_cause"]["none"] == {"days": 2, "right": 1, "named": ["none", "sensor_bias"]}
    assert not any(s["checks"].values())


def test_broken_config_is_forty_percent_off_within_bounds(ow, config):
    cfg, vals = ow.broken_config(config)
    for name, f in ow.BROKEN.items():
        p = config.parameters[name]
        assert vals[name] == pytest.approx(min(max(p.value * f, p.low), p.high))
        assert cfg.parameters[name].value == pytest.approx(vals[name])


def test_quick_defaults_and_explicit_options(ow):
    a = ow.parse_args(["--quick"])
    assert (a.plants, a.hours, a.trials, a.days_per_cause) == (1, 12.0, 6, 1)
    b = ow.parse_args(["--plants", "3", "--parts", "diagnosis", "--no-matched"])
    assert (b.plants, b.hours, b.trials, b.days_per_cause) == (3, 48.0, 100, 4)
    assert b.parts == ["diagnosis"] and not b.matched
    with pytest.raises(SystemExit):
        ow.parse_args(["--parts", "calibration,bogus"])


@pytest.mark.slow
def test_quick_run_prints_one_json_document(ow, capsys, tmp_path):
    out = tmp_path / "ow.json"
    assert ow.main(["--quick", "--seed", "20260105", "--no-matched", "--parts",
                    "calibration,estimator", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc == json.loads(out.read_text())
    assert doc["seed"] == 20260105 and doc["seed_source"] == "--seed"
    ind = doc["independent"]
    assert set(ind["timings_s"]) >= {"calibration", "estimator", "total"}
    plant = ind["calibration"]["plants"][0]
    assert "error" not in plant, plant.get("error")
    assert set(plant["calibrated_rmse"]) == {"T_dryer_out", "T_cyclone_out", "moisture_out"}
    days = ind["estimator"]["days"]
    assert [d["effect"] for d in days] == ["none", "inlet_moisture"]
    assert all("error" not in d for d in days + ind["estimator"]["broken_model"])
    assert 0.0 <= days[0]["moisture_out_min"] <= days[0]["moisture_out_max"] <= 1.0
    assert "estimator" in doc["summary"] and "diagnosis" not in doc["summary"]
