"""``benchmarks/open_world.py`` and its peers (``benchmarks/peers.py``): the plan, every peer
against hand numbers, the summaries (fast), and a ``--quick`` run (slow: simulates,
calibrates on history, estimates and diagnoses, minutes on two cores)."""

from __future__ import annotations

import json
import sys
from types import ModuleType

import numpy as np
import pandas as pd
import pytest
from paths import REPO
from script_modules import load_script

from softsensor.plant.effects import EFFECTS

BENCH = REPO / "benchmarks"


def _load(name: str) -> ModuleType:
    return load_script(BENCH / f"{name}.py")


@pytest.fixture(scope="module")
def ow() -> ModuleType:
    return _load("open_world")


@pytest.fixture(scope="module")
def peers(ow) -> ModuleType:
    return sys.modules["peers"]


W = 600 * 10**9


def test_stratified_draws_one_magnitude_per_stratum(ow):
    rng = np.random.default_rng(0)
    mags = sorted(ow.stratified(0.2, 0.6, 4, rng))
    assert len(mags) == 4
    for i, m in enumerate(mags):
        assert 0.2 + 0.1 * i <= m <= 0.2 + 0.1 * (i + 1)


def test_plan_has_history_before_every_cause_on_every_plant(ow):
    book = ow.SeedBook(12345)
    plan = ow.make_plan("independent", book, 2, 7, 2, 48.0)
    matched = ow.make_plan("model", book, 1, 3, 1, 48.0)
    seeds = [d.seed for p in (plan, matched) for d in [*sum(p.history, []), *p.tests]]
    assert len(seeds) == len(set(seeds))
    assert len(set(plan.plant_seeds)) == 2 and matched.plant_seeds == [None]
    for i in range(2):
        hist = plan.history[i]
        # seven consecutive 48 h records, then the test days after them
        assert [d.date for d in hist] == list(range(0, 14, 2))
        tests = [d for d in plan.tests if d.plant == i]
        assert len(tests) == 16 and min(d.date for d in tests) == 14
        assert len({d.date for d in tests}) == 16
        for c in ("none", *EFFECTS):
            assert sum(d.effect == c for d in tests) == 2
    for c, spec in EFFECTS.items():
        mags = [d.magnitude for d in plan.tests if d.effect == c]
        assert len(mags) == 4 and all(spec.detectable[0] <= m <= spec.detectable[1]
                                      for m in mags)
    again = ow.make_plan("independent", ow.SeedBook(12345), 2, 7, 2, 48.0)
    assert again.as_dict() == plan.as_dict()
    fixed = ow.make_plan("independent", ow.SeedBook(1), 9, 2, 1, 24.0, fixed=[11, 12])
    assert fixed.plant_seeds == [11, 12] and len(fixed.history) == 2


def _labs(rows: list[tuple[int, int, float]]) -> pd.DataFrame:
    """Lab results (sample window, log window, value) on the 600 s grid."""
    return pd.DataFrame({"sample_time_ns": [s * W + W // 2 for s, _, _ in rows],
                         "log_time_ns": [g * W + W // 2 for _, g, _ in rows],
                         "moisture_out": [v for _, _, v in rows],
                         "sample_id": [f"L{i}" for i in range(len(rows))]})


def test_hold_takes_the_latest_sample_among_the_arrived(peers):
    labs = _labs([(1, 3, 0.10), (4, 5, 0.12), (2, 6, 0.08)])  # the third arrives late
    ends = np.arange(1, 9) * W
    out = peers.hold_last_lab(labs, ends)
    assert np.isnan(out[:3]).all()
    np.testing.assert_array_equal(out[3:], [0.10, 0.10, 0.12, 0.12, 0.12])


def test_bias_update_adds_the_last_arrived_residual(peers):
    labs = _labs([(1, 2, 0.10), (3, 5, 0.20)])
    ends = np.arange(1, 8) * W
    at_end = np.linspace(0.0, 0.06, 7)
    out = peers.bias_updated(labs, ends, np.array([0.05, 0.15]), at_end)
    assert np.isnan(out[:2]).all()
    np.testing.assert_allclose(out[2:5], at_end[2:5] + 0.05)
    np.testing.assert_allclose(out[5:], at_end[5:] + 0.05)
    labs.loc[1, "moisture_out"] = 0.30
    out = peers.bias_updated(labs, ends, np.array([0.05, 0.15]), at_end)
    np.testing.assert_allclose(out[5:], at_end[5:] + 0.15)


class _Day:
    def __init__(self, scans: pd.DataFrame, labs: pd.DataFrame) -> None:
        self.scans, self.labs = scans, labs


def test_regression_recovers_a_linear_plant_and_is_exact_with_its_bias(peers):
    """On scans where the lab moisture is exactly linear in two signals, the regression
    fitted on them predicts a new day's moisture to round-off after its first lab."""
    rng = np.random.default_rng(3)
    t = np.arange(1, 600 * 20 + 1) * 10**9 * 10
    days = []
    for _ in range(3):
        scans = pd.DataFrame({s: rng.normal(size=len(t)) for s in peers.REGRESSION_SIGNALS},
                             index=t)
        wm = peers.window_means(scans)
        k = np.arange(2, 200, 7)
        sample = wm.index[k] - W // 2
        value = 0.1 + 0.02 * wm["m_fiber"].to_numpy()[k] - 0.01 * wm["T_air_in"].to_numpy()[k]
        labs = pd.DataFrame({"sample_time_ns": sample, "log_time_ns": sample + 3 * W,
                             "moisture_out": value, "sample_id": [str(i) for i in k]})
        days.append(_Day(scans, labs))
    model = peers.fit_regression(days[:2])
    test = days[2]
    ends = peers.window_means(test.scans).index.to_numpy()[10:]
    out = peers.regression_peer(model, test.scans, test.labs, ends)
    wm = peers.window_means(test.scans).reindex(ends)
    truth = 0.1 + 0.02 * wm["m_fiber"].to_numpy() - 0.01 * wm["T_air_in"].to_numpy()
    ok = np.isfinite(out)
    assert ok.sum() > 100
    # the whisper of ridge shrinks the slopes a little; the bias update takes the rest
    # measured: at most 1.2e-4 off (the truth's spread here is 2.8e-3)
    np.testing.assert_allclose(out[ok], truth[ok], atol=5e-4)


def test_time_difference_adds_the_model_change_since_the_sample(peers):
    series = pd.Series(np.arange(10) * 0.01, index=np.arange(1, 11) * W)
    labs = _labs([(2, 4, 0.5)])
    ends = np.arange(1, 11) * W
    out = peers.time_difference(series, labs, ends)
    assert np.isnan(out[:4]).all()  # logged at 4.5 windows: known from the tick ending at 5
    # sampled at 2.5 windows (the model's latest point before: 0.01), now at the end of
    # window k: 0.01 (k - 1)
    np.testing.assert_allclose(out[4:], 0.5 + (np.arange(5, 11) - 1) * 0.01 - 0.01)


def _day(cause: str, soft: float, hold: float, reg: float, floor: float, cov: float = 0.95,
         mi: float = 0.02, fb: float = 0.0) -> dict:
    rmse = {"softsensor": soft, "hold": hold, "regression": reg, "time_difference": hold,
            "floor": floor, "floor_open_loop": floor}
    return {"cause": cause, "rmse": rmse, "coverage95": cov, "moisture_in_rmse": mi,
            "fallback_share": fb, "target_day": max(0.5 * hold, 1.25 * floor),
            "tick_ms_median": 10.0}


def test_estimator_summary_checks_every_target(ow):
    good = [_day("none", 0.003, 0.008, 0.006, 0.002), _day("fouling_drift", 0.004, 0.009,
                                                         0.007, 0.003)]
    s = ow.estimator_summary(good)
    assert s["pass"] and s["below_hold"] == "2/2"
    assert s["pooled_rmse"]["softsensor"] == pytest.approx(np.sqrt((0.003**2 + 0.004**2) / 2))
    bad = ow.estimator_summary([*good, _day("none", 0.007, 0.006, 0.005, 0.004, fb=0.1)])
    c = bad["checks"]
    assert not c["below_hold"] and not c["below_regression"] and not c["fallback_clean"]
    assert bad["at_most_half_hold_or_floor"] == "2/3" and not c["half_hold"]
    assert not ow.estimator_summary([_day("none", 0.003, 0.008, 0.006, 0.002, cov=0.8)]
                                    )["checks"]["coverage"]
    assert not ow.estimator_summary([_day("none", 0.003, 0.008, 0.006, 0.002, mi=0.06)]
                                    )["checks"]["moisture_in_rmse"]


def test_diagnosis_summary_confusion_false_alarms_and_gains(ow):
    days = [{"cause": "none", "named": "none", "gain": 0.0, "right": True, "seed": 1},
            {"cause": "none", "named": "fouling_drift", "gain": 0.2, "right": False, "seed": 2},
            {"cause": "lab_delay", "named": "lab_delay", "gain": -0.1, "right": True, "seed": 3},
            {"cause": "input_lag", "error": "boom", "right": False, "seed": 4}]
    s = ow.diagnosis_summary(days)
    assert s["false_alarms"] == 1 and s["right"] == "2/4" and s["failed_days"] == 1
    assert s["confusion"]["none"]["fouling_drift"] == 1
    assert s["confusion"]["input_lag"]["error"] == 1
    assert [b["seed"] for b in s["named_without_positive_gain"]] == [3]
    assert not s["pass"]


def test_quick_defaults_and_explicit_options(ow):
    a = ow.parse_args(["--quick"])
    assert (a.plants, a.history, a.hours, a.trials) == (1, 3, 12.0, 20)
    b = ow.parse_args(["--plants", "3", "--history", "5", "--parts", "estimator",
                       "--plant-seeds", "11,12"])
    assert (b.plants, b.history, b.hours, b.trials) == (3, 5, 48.0, 200)
    assert b.parts == ["estimator"] and b.plant_seeds == [11, 12]
    with pytest.raises(SystemExit):
        ow.parse_args(["--parts", "bogus"])


@pytest.mark.slow
def test_quick_run_prints_one_json_document(ow, capsys, tmp_path):
    out = tmp_path / "ow.json"
    assert ow.main(["--quick", "--seed", "20260105", "--no-matched", "--parts",
                    "calibration,estimator", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc == json.loads(out.read_text())
    est = doc["independent"]["estimator"]
    assert len(est["days"]) == 8 and est["summary"]["failed_days"] == 0
    assert set(est["summary"]["pooled_rmse"]) == set(ow.METHODS)
