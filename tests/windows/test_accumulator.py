"""Scans to 600 s windows: alignment, means of good values, thresholds, gaps; no network."""

from __future__ import annotations

import math
import random

import numpy as np
import pandas as pd
import pytest

from softsensor.errors import ConfigError, IngestError
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.accumulator import (
    MODEL_SIGNALS,
    WindowAccumulator,
    WindowSettings,
    window_end,
    windows_from_frame,
    windows_from_scans,
)

NS = 10**9
P = 600 * NS
E0 = 2_916_666 * P  # a window boundary (2025-06-15T15:00:00Z)


def full_scan(value: float = 1.0) -> dict:
    return dict.fromkeys(SCAN_SIGNALS, value)


def scans_of_window(end: int, n: int = 60, value=lambda i: 1.0) -> list[tuple[int, dict]]:
    """``n`` scans every 10 s in the window ending at ``end``, the last one on ``end``."""
    return [(end - P + (i + 1) * 10 * NS, full_scan(value(i))) for i in range(n)]


def test_settings() -> None:
    s = WindowSettings()
    assert s.period_ns == P and s.expected_scans == 60 and s.min_good == 30
    assert WindowSettings(min_fraction=0.8).min_good == 48
    assert set(MODEL_SIGNALS) == {"T_air_in", "m_air", "m_fiber", "T_fiber_in", "m_steam",
                                  "T_amb", "H_amb"}
    with pytest.raises(ConfigError, match="window.period_s"):
        WindowSettings(period_s=0)
    with pytest.raises(ConfigError, match="window.min_fraction"):
        WindowSettings(min_fraction=1.5)
    with pytest.raises(ConfigError, match="'T_foo'"):
        WindowSettings(required=("T_foo",))


def test_window_end_alignment() -> None:
    assert window_end(E0, P) == E0  # a scan on the boundary closes that window
    assert window_end(E0 + 1, P) == E0 + P
    assert window_end(E0 - 1, P) == E0
    assert window_end(0, P) == 0 and window_end(-1, P) == 0


def test_full_window_means() -> None:
    acc = WindowAccumulator()
    out = []
    for t, body in scans_of_window(E0, value=lambda i: float(i)):
        out += acc.add(t, body)
    assert out == []  # the window closes only when a later scan (or time) arrives
    (w,) = acc.add(E0 + 10 * NS, full_scan())
    assert (w.start_ns, w.end_ns, w.n_scans, w.stale) == (E0 - P, E0, 60, False)
    assert w.means["T_air_in"] == pytest.approx(29.5)
    assert all(w.n_good[name] == 60 for name in SCAN_SIGNALS)
    assert w.reasons == {}


def test_nulls_and_non_finite_values_are_not_good() -> None:
    acc = WindowAccumulator()
    for i, (t, body) in enumerate(scans_of_window(E0)):
        body["T_cyclone_out"] = None if i % 3 else 340.0  # 20 good of 60
        body["T_dryer_out"] = math.nan if i < 10 else 350.0 + (i % 2)  # 50 good
        body["flap_cmd"] = math.inf if i == 0 else 50.0
        body.pop("T_sp")  # missing entirely
        acc.add(t, body)
    (w,) = acc.flush()
    assert w.n_good["T_cyclone_out"] == 20 and w.means["T_cyclone_out"] is None
    assert "20 good values in 60 scans, 30 of 60 expected needed" == w.reasons["T_cyclone_out"]
    assert w.means["T_dryer_out"] == pytest.approx(350.5) and w.n_good["T_dryer_out"] == 50
    assert w.means["flap_cmd"] == 50.0 and w.n_good["flap_cmd"] == 59
    assert w.means["T_sp"] is None and w.n_good["T_sp"] == 0
    assert not w.stale  # outlet temperatures and T_sp are not model inputs


def test_threshold_boundary() -> None:
    for good, expect_none in [(30, False), (29, True)]:
        acc = WindowAccumulator()
        for i, (t, body) in enumerate(scans_of_window(E0)):
            body["m_air"] = 80.0 if i < good else None
            acc.add(t, body)
        (w,) = acc.flush()
        assert (w.means["m_air"] is None) is expect_none
        assert w.stale is expect_none  # m_air is a model input


def test_few_scans_make_the_window_stale() -> None:
    acc = WindowAccumulator()
    for t, body in scans_of_window(E0, n=29):
        acc.add(t, body)
    (w,) = acc.flush()
    assert w.stale and w.n_scans == 29
    assert w.reasons["scans"] == "29 scans, 30 of 60 expected needed"
    assert all(v is None for v in w.means.values())


def test_gaps_emit_stale_windows() -> None:
    acc = WindowAccumulator()
    for t, body in scans_of_window(E0):
        acc.add(t, body)
    out = acc.add(E0 + 3 * P + 5 * NS, full_scan())  # in the window ending at E0 + 4 P
    assert [(w.end_ns - E0) // P for w in out] == [0, 1, 2, 3]
    assert [w.stale for w in out] == [False, True, True, True]
    assert out[1].n_scans == 0 and out[1].reasons["scans"] == "no scans (gap in the data)"
    assert out[1].start_ns == E0 and out[2].end_ns == E0 + 2 * P
    assert acc.current_end_ns == E0 + 4 * P


def test_advance_without_scans() -> None:
    acc = WindowAccumulator()
    assert acc.advance(E0) == []  # nothing started yet
    for t, body in scans_of_window(E0 + P):
        acc.add(t, body)
    assert acc.advance(E0 + P - 1) == []
    (w,) = acc.advance(E0 + P)
    assert w.end_ns == E0 + P and not w.stale
    out = acc.advance(E0 + 3 * P + 7)
    assert [w.end_ns for w in out] == [E0 + 2 * P, E0 + 3 * P] and all(w.stale for w in out)
    assert acc.advance(E0 + 3 * P + 8) == []
    # a late scan for an emitted window is dropped and counted
    assert acc.add(E0 + 2 * P, full_scan()) == [] and acc.n_late == 1
    gap, w = acc.add(E0 + 4 * P + 1, full_scan()) + acc.flush()
    assert (gap.end_ns, gap.n_scans, gap.stale) == (E0 + 4 * P, 0, True)
    assert w.end_ns == E0 + 5 * P and w.n_scans == 1


def test_start_ns_emits_leading_gap() -> None:
    acc = WindowAccumulator(start_ns=E0)
    out = acc.add(E0 + 2 * P, full_scan())
    assert [w.end_ns for w in out] == [E0 + P] and out[0].n_scans == 0
    assert acc.add(E0 - 5, full_scan()) == [] and acc.n_late == 1


def test_unknown_signal_is_an_error() -> None:
    with pytest.raises(IngestError, match="T_air_inlet"):
        WindowAccumulator().add(E0, {"T_air_inlet": 450.0})


def test_out_of_order_within_window_and_determinism() -> None:
    scans = scans_of_window(E0, value=lambda i: 400.0 + 0.1 * i)
    shuffled = scans[:]
    random.Random(3).shuffle(shuffled)
    a = windows_from_scans(scans)
    b = windows_from_scans(shuffled)
    assert a[0].means == b[0].means  # fsum: exactly the same regardless of order
    assert windows_from_scans(scans) == a


def test_windows_from_frame_matches_stream() -> None:
    rng = np.random.default_rng(0)
    t = E0 + np.arange(1, 400) * 10 * NS
    data = {name: rng.normal(300.0, 1.0, t.size) for name in SCAN_SIGNALS}
    df = pd.DataFrame(data, index=pd.Index(t, name="log_time_ns"))
    df.loc[df.index[60:100], "m_air"] = np.nan
    wf = windows_from_frame(df)
    ws = windows_from_scans((int(ti), {k: (None if math.isnan(v) else v) for k, v in row.items()})
                            for ti, row in zip(t, df.to_dict("records"), strict=True))
    assert wf == ws
    assert [w.end_ns for w in wf] == [E0 + k * P for k in range(1, 8)]
    assert wf[1].means["m_air"] is None and wf[1].stale  # 40 of 60 missing
    assert wf[0].means["T_amb"] == pytest.approx(df["T_amb"].iloc[:60].mean(), rel=1e-12)


def test_end_ns_pads_with_gap_windows() -> None:
    ws = windows_from_scans(scans_of_window(E0), end_ns=E0 + 2 * P - 1)
    assert [w.end_ns for w in ws] == [E0, E0 + P, E0 + 2 * P]
    assert [w.stale for w in ws] == [False, True, True]
