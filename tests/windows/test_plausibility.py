"""Plausibility at the edge and at publication (issue 25, items 1 and 3), without a network:
the judge's rules one by one, a checkpoint that re-judges its open window alike, a config
that changes a limit, and the service never calling an unphysical estimate ``ok``."""

from __future__ import annotations

import math
from typing import Any

import pytest

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate
from softsensor.messages import Window
from softsensor.plantconfig import load_plant_config, plant_config_from_dict
from softsensor.service.estimator_service import EstimatorService
from softsensor.windows.accumulator import WindowAccumulator, window_settings
from softsensor.windows.plausibility import (
    InputJudge,
    estimate_problems,
    estimate_ranges,
    plausibility_from_config,
)

S = 10**9
T0 = 1_767_571_200 * S
GOOD = {"T_air_in": 480.0, "m_air": 82.0, "m_fiber": 6.0, "T_fiber_in": 370.0,
        "m_steam": 0.5, "T_amb": 283.0, "H_amb": 0.006, "flap_cmd": 40.0, "T_sp": 348.0,
        "T_dryer_out": 348.0, "T_cyclone_out": 346.0}


def _judge_series(values: list[float], name: str = "T_air_in") -> list[bool]:
    judge = InputJudge(plausibility_from_config(load_plant_config()))
    return [judge.judge(name, T0 + 10 * S * i, v) is None for i, v in enumerate(values)]


def test_range_magnitude_and_rate():
    assert _judge_series([480.0, 690.0, 481.0]) == [True, False, True]  # range
    assert _judge_series([480.0, 1e308, -1e308, 481.0]) == [True, False, False, True]
    assert _judge_series([480.0, 600.0, 600.0, 480.0]) == [True, False, False, True]  # spike
    # a fast but physical move (3 K/s for a minute, a burner trip) is followed
    assert all(_judge_series([560.0 - 30.0 * i for i in range(6)]))
    # a set point moves in steps: no rate check
    assert all(_judge_series([348.0, 358.0, 340.0], name="T_sp"))


def test_a_new_level_is_believed_after_it_held_steady_and_after_an_outage():
    steps = [480.0] * 3 + [560.0] * 70  # a level 80 K higher for 700 s
    ok = _judge_series(steps)
    assert ok[:3] == [True] * 3 and not any(ok[3:63]) and all(ok[63:])
    judge = InputJudge(plausibility_from_config(load_plant_config()))
    assert judge.judge("T_air_in", T0, 480.0) is None
    assert judge.judge("T_air_in", T0 + 3600 * S, 560.0) is None  # after an hour of nothing


def test_an_accumulator_restored_mid_window_judges_as_it_did():
    ws = window_settings(load_plant_config())
    scans = [(T0 + 10 * S * (i + 1), dict(GOOD, T_air_in=600.0 if 62 <= i < 70 else 480.0))
             for i in range(130)]
    live = WindowAccumulator(ws)
    out_live = [w for t, b in scans for w in live.add(t, b)]
    # stop after scan 65 (inside the spike), restore from the state at the window's start
    first = WindowAccumulator(ws)
    done = [w for t, b in scans[:66] for w in first.add(t, b)]
    again = WindowAccumulator(ws, start_ns=done[-1].end_ns,
                              judge_state=first.judge_state_at_window_start)
    open_window = [(t, b) for t, b in scans[:66] if t > done[-1].end_ns]
    for t, b in open_window:
        again.add(t, b)
    out_again = done + [w for t, b in scans[66:] for w in again.add(t, b)]
    assert [w.means for w in out_again] == [w.means for w in out_live]
    assert out_live[1].refused == {"T_air_in": 8}


def test_a_plausibility_table_changes_a_limit_and_is_checked():
    base = load_plant_config()
    doc = {"plausibility": {"T_air_in": {"high": 700.0}, "hold_s": 120}}
    raw = _raw_config(base)
    cfg = plant_config_from_dict({**raw, **doc}, "site.toml")
    p = plausibility_from_config(cfg)
    assert p.limits["T_air_in"].high == 700.0 and p.limits["T_air_in"].low == 400.0
    assert p.hold_s == 120.0
    bad = plant_config_from_dict({**raw, "plausibility": {"T_air_in": {"high": 100.0}}},
                                 "site.toml")
    with pytest.raises(ConfigError, match="plausibility.T_air_in.high must be > low"):
        plausibility_from_config(bad)
    unknown = plant_config_from_dict({**raw, "plausibility": {"T_foo": {}}}, "site.toml")
    with pytest.raises(ConfigError, match=r"plausibility\.T_foo is not a known key \(known: h"):
        plausibility_from_config(unknown)
    # a signal's table is read as the one SignalLimits it becomes (no second dataclass of the
    # same keys): its errors name the dotted key
    for table, match in [({"hihg": 700.0}, r"plausibility\.T_air_in\.hihg is not a known key "
                                           r"\(known: low, high, max_rate, max_step\)"),
                         (5, r"\[plausibility\.T_air_in\] must be a table, got int"),
                         ({"max_rate": -1.0}, r"plausibility\.T_air_in\.max_rate must be >= 0"),
                         ({"low": "x"}, r"plausibility\.T_air_in\.low must be a number")]:
        wrong = plant_config_from_dict({**raw, "plausibility": {"T_air_in": table}}, "site.toml")
        with pytest.raises(ConfigError, match=match):
            plausibility_from_config(wrong)


def _raw_config(cfg) -> dict[str, Any]:
    import tomllib

    with open(cfg.source, "rb") as f:
        return tomllib.load(f)


class _Says:
    """An estimator that says ``ok`` to whatever it is told to publish."""

    kind = "fake"

    def __init__(self, body: dict[str, Any]) -> None:
        self.body = body

    def tick(self, window: Window) -> Estimate:
        return Estimate.from_body(dict(self.body, status="stale" if window.stale else "ok",
                                       detail="fine", window_start_ns=window.start_ns,
                                       window_end_ns=window.end_ns, estimator=self.kind))

    def add_lab(self, lab) -> None:
        return None

    def checkpoint(self) -> dict[str, Any]:
        return {}

    def restore(self, snapshot: dict[str, Any]) -> None:
        pass


SANE = {"moisture_out": 0.1, "moisture_out_std": 0.01, "moisture_in": 1.0,
        "moisture_in_std": 0.1, "T_dryer_out_model": 348.0, "T_cyclone_out_model": 346.0}


@pytest.mark.parametrize(("change", "why"), [
    ({"moisture_out": 1.37}, "moisture_out 1.37 outside 0..1"),
    ({"moisture_out": -0.01}, "moisture_out -0.01 outside 0..1"),
    ({"moisture_out": math.nan}, "moisture_out is missing"),
    ({"moisture_in": 3.0}, "moisture_in 3 outside 0.3..2.5"),
    ({"T_dryer_out_model": 900.0}, "T_dryer_out_model 900 outside 300..420"),
])
def test_an_unphysical_estimate_is_never_ok(change, why):
    svc = EstimatorService(_Says(dict(SANE, **change)),
                           window_settings(load_plant_config()),
                           ranges=estimate_ranges(plausibility_from_config(load_plant_config()),
                                                  (0.3, 2.5)))
    out = [o for t in range(10, 640, 10) for o in svc.on_scan(T0 + t * S, dict(GOOD))]
    i = next(i for i, o in enumerate(out) if o.kind == "estimate")
    est, health = out[i].to_body(), out[i + 1].to_body()  # the health published with the tick
    assert est["status"] == health["status"] == "degraded"
    assert est["detail"].startswith("not physical: " + why), est["detail"]
    assert svc.stats.unphysical_ticks == 1
    assert estimate_problems(SANE, svc.ranges) == []
