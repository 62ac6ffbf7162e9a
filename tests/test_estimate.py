"""The published estimate and health (``softsensor/estimate.py``): status the worst of the
reasons, detail their sentences in order, bodies written in one place and read back whole."""

from __future__ import annotations

import math
from types import MappingProxyType

import pytest

from softsensor.estimate import (
    CONTRACT_FIELDS,
    Blend,
    Estimate,
    FilterTerms,
    Health,
    Reason,
    SourceEstimate,
    Stall,
    WindowFacts,
    worst,
)

T = 1_767_607_800 * 10**9


def estimate(**changes) -> Estimate:
    terms = FilterTerms(0.004, -0.002, 0.007, 0.0, 2.1, 0.5, 0.06, 0.21, 347.4, 343.4, 0.36,
                        2, False, ("L1",), "estimator defaults")
    blend = Blend(0.1048, 0.0081, MappingProxyType({
        "physics": SourceEstimate(0.99, 0.1048, 0.0081),
        "hold": SourceEstimate(0.01, 0.13, 0.0208),
        "regression": SourceEstimate(0.0, None, None)}), 0.93, (0, 5), "physics")
    facts = WindowFacts("dryer1", 60, False, 347.5, 343.6, {"T_amb": 2}, {"T_amb": "below"})
    base = dict(window_start_ns=T - 600 * 10**9, window_end_ns=T, estimator="ukf",
                moisture_out=0.105, moisture_out_std=0.008, moisture_in=1.014,
                moisture_in_std=0.022, T_dryer_out_model=347.5, T_cyclone_out_model=343.6,
                lab_updated=True, reasons=(Reason("ok", "innovations consistent"),),
                notes=("matched",), filter=terms, blend=blend, window=facts)
    return Estimate(**{**base, **changes})


def test_the_status_is_the_worst_reason_and_the_detail_their_sentences_in_order():
    e = estimate().judged(Reason("degraded", "not physical: x"), first=True)
    e = e.judged(Reason("ok", "implausible inputs refused: T_amb 2"))
    assert e.status == "degraded"
    assert e.detail == ("not physical: x; innovations consistent; implausible inputs refused: "
                        "T_amb 2")
    assert e.judged(Reason("stale", "stale window")).status == "stale"
    assert estimate(reasons=()).status == "ok" and estimate(reasons=()).detail == "ok"
    # a status no screen knows is not good
    assert worst("ok", "weird") == "degraded" and worst() == "ok"


def test_a_body_carries_the_contract_and_reads_back_to_the_same_body():
    e = estimate()
    body = e.to_body()
    assert all(k in body for k in (*CONTRACT_FIELDS, "lab_updated", "status", "detail"))
    assert body["sources"]["hold"]["moisture_out"] == 0.13 and body["band_misses"] == [0, 5]
    assert body["inputs_refused"] == {"T_amb": 2} and body["unit"] == "dryer1"
    assert body["labs_applied"] == ["L1"] and body["window_end_ns"] == e.time_ns == T
    again = Estimate.from_body(body)
    assert again.to_body() == body
    assert again.status == e.status and again.detail == e.detail


def test_an_estimate_without_the_filter_peers_or_window_leaves_their_fields_out():
    e = estimate(filter=None, blend=None, window=None, lab_residual={"L1": 0.003})
    body = e.to_body()
    assert "nis" not in body and "sources" not in body and "n_scans" not in body
    assert body["lab_residual"] == {"L1": 0.003}
    assert Estimate.from_body(body).to_body() == body


def test_a_missing_value_reads_as_none_never_nan():
    e = Estimate.from_body({"moisture_out": math.nan, "moisture_in": None, "status": "ok"})
    assert e.moisture_out is None and e.moisture_in is None


def health(**changes) -> Health:
    base = dict(time_ns=T, unit="dryer1", estimator="ukf", tick=Reason("ok", "consistent"),
                input=Reason("ok", "every model input read"), lab=Reason("ok", ""),
                counters={"ticks": 5, "scans": 300}, window_end_ns=T)
    return Health(**{**base, **changes})


def test_health_is_the_worst_part_and_says_each_part_that_is_not_ok():
    assert health().status == "ok" and health().detail == "consistent"
    h = health(input=Reason("degraded", "no good value of T_air_in"),
               lab=Reason("degraded", "lab: no lab result accepted for 9.0 h"))
    assert h.status == "degraded"
    assert h.detail == "input: no good value of T_air_in; lab: no lab result accepted for 9.0 h"
    assert health(tick=Reason("stale", "stale window")).status == "stale"


def test_the_daemons_news_are_fields_not_edited_text():
    h = health().at(T + 10, recording="disk full")
    assert h.status == "ok" and h.detail == "consistent; recording: disk full"
    assert h.to_body()["recording"] == "disk full" and h.time_ns == T + 10
    assert health().at(T, recording="ok").detail == "consistent"  # nothing to say
    stalled = h.at(T + 20, stall=Stall(1271.0, 3, 600.0))
    body = stalled.to_body()
    assert body["status"] == "stale" and body["stalled"] is True and body["pending"] == 3
    assert body["detail"].startswith("stalled: no estimate for 1271 s")
    assert body["detail"].endswith("; recording: disk full")
    assert body["ticks"] == 5  # the service's counters stay with a stalled health


def test_a_health_body_reads_back_to_the_same_body():
    cases = [
        health(lab=Reason("degraded", "lab: silent"), recording="disk full",
               inputs_dropped={"rate": 3}, recording_capped={"/plant/scan": 8}),
        health(input=Reason("degraded", "no good value of T_air_in"),
               lab=Reason("degraded", "lab: silent 9 h")),
        health(tick=Reason("degraded", "inconsistent"), input=Reason("stale", "no scans"))
        .at(T + 5, stall=Stall(1271.0, 3, 600.0)),
    ]
    for h in cases:
        body = h.to_body()
        again = Health.from_body(body, h.time_ns)
        assert again == h, (again, h)
        assert again.to_body() == body
    # a body that says only its status and detail keeps both
    short = Health.from_body({"status": "degraded", "detail": "inconsistent"}, T)
    assert short.status == "degraded" and short.detail == "inconsistent"


def test_estimates_and_health_are_frozen():
    with pytest.raises(AttributeError):
        estimate().moisture_out = 0.2  # type: ignore[misc]
    with pytest.raises(AttributeError):
        health().recording = "ok"  # type: ignore[misc]
