"""The what-if's bookkeeping (softsensor.advisor.replay) on a hand-made recording."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from softsensor.advisor.advice import Advice
from softsensor.advisor.replay import refusal_kind, situations, what_if
from softsensor.advisor.settings import AdvisorSettings
from softsensor.signals import SCAN_SIGNALS

T0 = 1_699_999_200 * 10**9  # on a UTC hour
W = 600 * 10**9


def _recording(hours: int = 3):
    """Scans every 10 s with m_fiber stepping from 6.0 to 6.6 kg/s at 1.5 h, and ticks every
    600 s; the health degraded from 2 h on."""
    t = T0 + np.arange(0, hours * 360) * 10 * 10**9
    scans = pd.DataFrame({n: np.full(t.size, 1.0) for n in SCAN_SIGNALS}, index=t)
    scans["m_fiber"] = np.where(t < T0 + 5400 * 10**9, 6.0, 6.6)
    scans["T_sp"] = 348.0
    scans.loc[scans.index[5], "T_air_in"] = np.nan  # a failed read is left out of the mean
    ends = T0 + np.arange(1, hours * 6 + 1) * W
    est = [(int(e), {"window_start_ns": int(e - W), "window_end_ns": int(e),
                     "moisture_out": 0.09, "moisture_out_std": 0.005, "moisture_in": 1.0})
           for e in ends]
    health = [(int(T0 + W), {"status": "ok", "detail": "fine"}),
              (int(T0 + 7200 * 10**9), {"status": "degraded", "detail": "innovations"})]
    return scans, est, health


def test_one_situation_per_hour_with_its_window_health_and_recent_production():
    scans, est, health = _recording()
    sits = situations(scans, est, health, AdvisorSettings())
    # the first tick of each UTC hour
    assert [(s.time_ns - T0) // 10**9 for s in sits] == [600, 3600, 7200, 10800]
    assert sits[0].inputs["T_air_in"] == pytest.approx(1.0)  # the NaN left out
    assert sits[0].inputs["m_fiber"] == pytest.approx(6.0)
    assert [s.health for s in sits] == ["ok", "ok", "degraded", "degraded"]
    assert sits[2].health_detail == "innovations"
    # the last hour before 7200 s holds the step from 6.0 to 6.6 kg/s
    assert min(sits[2].recent_m_fiber) == pytest.approx(6.0)
    assert max(sits[2].recent_m_fiber) == pytest.approx(6.6)
    assert len(sits[2].recent_m_fiber) == 6


def test_what_if_sums_the_advised_hours_and_counts_the_refusals():
    scans, est, health = _recording()
    sits = situations(scans, est, health, AdvisorSettings())
    ok = Advice(0, True, "go", duty_kw=15000.0, duty_advised_kw=14000.0, p_within_max=0.99)
    no = Advice(0, False, "health is degraded: innovations")
    w = what_if([ok, ok, no, no], sits, AdvisorSettings())
    assert w.hours == 4 and w.hours_advised == 2
    assert w.energy_saved_kwh == pytest.approx(2000.0)
    assert w.fibre_t == pytest.approx(2 * 6.0 * 3.6)
    assert w.saved_kwh_per_t == pytest.approx(2000.0 / (2 * 21.6))
    assert w.expected_hours_above_max == pytest.approx(0.02)
    assert w.refusals == {"health is degraded": 2}


def test_refusal_kinds_group_by_their_words_not_their_numbers():
    assert refusal_kind("production change: the dry-fibre flow moved 5.5 to 6.1 kg/s") == \
        "production change"
    assert refusal_kind("m_fiber 7.8 kg/s is outside the envelope") == "m_fiber"
    assert refusal_kind("the set point moved 1.0 K in the last 60 min") == \
        "the set point moved"
