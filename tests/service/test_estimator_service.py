"""The estimator service without a network: windows, ticks, lab order, health, checkpoints."""

from __future__ import annotations

import json
import logging
import math
import re
from typing import Any

import pytest

from softsensor.configfile import read_toml
from softsensor.errors import ConfigError, EstimationError
from softsensor.estimate import Estimate, FilterTerms, Reason
from softsensor.estimation.interface import LabResult, Window
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import load_plant_config, plant_config_from_dict
from softsensor.service.checkpoint import CheckpointStore
from softsensor.service.clock import ScaledClock
from softsensor.service.estimator_service import EstimatorService, Output
from softsensor.service.estimators import make_estimator
from softsensor.service.logs import JsonFormatter, KeyValueFormatter, event
from softsensor.service.settings import ServiceSettings, service_settings
from softsensor.service.warmup import N_WINDOWS, warm_up
from softsensor.signals import SCAN_SIGNALS
from softsensor.windows.accumulator import MODEL_SIGNALS, WindowSettings

S = 10**9
T0 = 1_767_571_200 * S  # 2026-01-05T00:00:00Z, a multiple of 600 s
GOOD = {"T_air_in": 480.0, "m_air": 82.0, "m_fiber": 6.0, "T_fiber_in": 370.0,
        "m_steam": 0.5, "T_amb": 283.0, "H_amb": 0.006, "flap_cmd": 40.0, "T_sp": 348.0,
        "T_dryer_out": 348.0, "T_cyclone_out": 346.0}


class FakeEstimator:
    """Records what the service hands it; refuses labs wetter than 0.5 kg/kg."""

    kind = "fake"

    def __init__(self, fail_at: int | None = None) -> None:
        self.events: list[tuple[Any, ...]] = []
        self.fail_at = fail_at
        self._lab = False

    def tick(self, window: Window) -> Estimate:
        if self.fail_at is not None and window.end_ns == self.fail_at:
            raise EstimationError("covariance lost definiteness")
        self.events.append(("tick", window.end_ns, window.stale, window.n_scans))
        lab, self._lab = self._lab, False
        # NaN where a value could not be given, as a model that failed one output returns it
        terms = FilterTerms(*[math.nan] * 10, nis=math.nan, nis_dof=0, fallback=False,
                            labs_applied=(), discrepancy_priors="fake")
        return Estimate(window.start_ns, window.end_ns, self.kind, 0.1, 0.01, 1.0, 0.1, 348.0,
                        math.nan, lab_updated=lab, filter=terms, reasons=(
                            Reason("stale" if window.stale else "ok", "fake"),))

    def add_lab(self, lab: LabResult) -> str | None:
        self.events.append(("lab", lab.sample_id))
        if lab.moisture_out > 0.5:
            return "too wet"
        self._lab = True
        return None

    def checkpoint(self) -> dict[str, Any]:
        return {"events": [list(e) for e in self.events]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        self.events = [tuple(e) for e in snapshot["events"]]


def scans(first_s: int, last_s: int, **changes: Any):
    for t in range(first_s, last_s + 1, 10):
        yield T0 + t * S, dict(GOOD, **changes)


def feed(service: EstimatorService, messages) -> list[Output]:
    out: list[Output] = []
    for kind, t, body in messages:
        out.extend(service.on_message(kind, body, t))
    return out


def lab(sample_id: str, sample_s: int, value: float = 0.1) -> dict[str, Any]:
    return {"sample_time_ns": T0 + sample_s * S, "moisture_out": value, "sample_id": sample_id}


def ticks(outputs: list[Output]) -> list[int]:
    return [(o.time_ns - T0) // S for o in outputs if o.kind == "estimate"]


# --- windows and ticks ----------------------------------------------------------------------


def test_a_window_is_ticked_once_a_scan_tick_delay_past_its_end_arrives() -> None:
    svc = EstimatorService(FakeEstimator(), tick_delay_s=30.0)
    assert ticks(feed(svc, (("scan", t, b) for t, b in scans(10, 620)))) == []
    out = feed(svc, [("scan", T0 + 630 * S, GOOD)])
    assert ticks(out) == [600]
    est = next(o for o in out if o.kind == "estimate")
    assert est.time_ns == T0 + 600 * S and est.to_body()["n_scans"] == 60
    assert est.to_body()["stale"] is False and est.to_body()["unit"] == "dryer1"
    # NaN never reaches the bus nor the operator outputs: an estimate holds None for what
    # could not be given, every field (not a list of six), whoever built it
    assert est.to_body()["T_cyclone_out_model"] is None and est.to_body()["nis"] is None
    assert [o.kind for o in out] == ["estimate", "health"]
    assert out[1].to_body()["status"] == "ok" and out[1].time_ns == est.time_ns


def test_gaps_and_sparse_windows_are_stale() -> None:
    fake = FakeEstimator()
    svc = EstimatorService(fake, tick_delay_s=0.0)
    msgs = [("scan", t, b) for t, b in scans(10, 600)]
    msgs += [("scan", t, b) for t, b in scans(610, 700)]  # 10 scans: too few
    msgs += [("scan", t, b) for t, b in scans(1810, 1900)]  # then 1200 s without scans
    feed(svc, msgs)
    assert fake.events == [("tick", T0 + 600 * S, False, 60), ("tick", T0 + 1200 * S, True, 10),
                           ("tick", T0 + 1800 * S, True, 0)]
    assert svc.stats.stale_ticks == 2 and svc.stats.ticks == 3


def test_lab_results_reach_the_estimator_by_log_time_whatever_the_arrival_order() -> None:
    """A lab logged before a window's end is applied before that window's tick, also when
    it arrives after the scan that closed the window (within the tick delay)."""
    labs = [("lab", T0 + 590 * S, lab("A", 100)), ("lab", T0 + 605 * S, lab("B", 200)),
            ("lab", T0 + 700 * S, lab("C", 300, 0.9))]
    in_order = sorted([*(("scan", t, b) for t, b in scans(10, 1300)), *labs],
                      key=lambda m: m[1])
    late = [m for m in in_order if m[0] == "scan"]
    i = next(i for i, m in enumerate(late) if m[1] == T0 + 620 * S)
    late[i:i] = labs  # arrive 20 s after the window closed, 10 s before the tick
    results = []
    for msgs in (in_order, late):
        fake = FakeEstimator()
        svc = EstimatorService(fake, tick_delay_s=30.0)
        outs = feed(svc, msgs)
        results.append((fake.events, [o.to_body() for o in outs if o.kind == "estimate"]))
        assert svc.stats.labs_accepted == 2 and svc.stats.labs_refused == 1
    assert results[0] == results[1]
    events = results[0][0]
    assert events[:3] == [("lab", "A"), ("tick", T0 + 600 * S, False, 60), ("lab", "B")]
    assert events.index(("lab", "C")) < events.index(("tick", T0 + 1200 * S, False, 60))
    assert [b["lab_updated"] for b in results[0][1]] == [True, True]


def test_malformed_scans_and_labs_are_counted_not_fatal() -> None:
    svc = EstimatorService(FakeEstimator())
    assert svc.on_scan(T0 + 10 * S, dict(GOOD, T_bogus=1.0)) == []
    assert svc.stats.bad_scans == 1 and svc.stats.scans == 0
    # a refused lab result is told in health at once, not at the next tick
    (h,) = svc.on_lab({"moisture_out": 0.1, "sample_id": "X"}, T0)
    assert h.kind == "health" and "sample_time_ns" in h.to_body()["last_lab_refusal"]
    (h,) = svc.on_lab(lab("Y", 10, value=math.inf), T0 + 20 * S)
    assert h.to_body()["labs_refused"] == 2 and h.to_body()["last_lab_refusal_ns"] == T0 + 20 * S
    assert svc.stats.labs_refused == 2
    svc.on_scan(T0 + 20 * S, GOOD)
    health = svc._health(T0 + 20 * S).to_body()
    assert "not finite" in health["last_lab_refusal"] and health["labs_refused"] == 2


def test_a_failing_estimator_degrades_health_and_the_service_goes_on() -> None:
    svc = EstimatorService(FakeEstimator(fail_at=T0 + 1200 * S), tick_delay_s=0.0)
    out = feed(svc, (("scan", t, b) for t, b in scans(10, 1810)))
    assert ticks(out) == [600, 1800]
    failed = [o.to_body() for o in out if o.kind == "health" and o.time_ns == T0 + 1200 * S]
    assert failed[0]["status"] == "degraded" and "covariance" in failed[0]["detail"]
    assert svc.stats.failed_ticks == 1


# --- health ---------------------------------------------------------------------------------


def test_health_on_every_tick_and_on_input_changes_only() -> None:
    svc = EstimatorService(FakeEstimator(), tick_delay_s=0.0)
    first = svc.on_scan(T0 + 10 * S, GOOD)
    assert [o.to_body()["status"] for o in first] == ["stale"]  # no window yet
    assert "first complete window" in first[0].to_body()["detail"]
    assert feed(svc, (("scan", t, b) for t, b in scans(20, 600))) == []  # nothing changed
    out = svc.on_scan(T0 + 610 * S, GOOD)
    assert [(o.kind, o.status) for o in out] == [("estimate", "ok"), ("health", "ok")]
    quality = {"T_air_in": "not_connected: no connection to 127.0.0.1:502"}
    out = svc.on_scan(T0 + 620 * S, dict(GOOD, T_air_in=None, quality=quality))
    (h,) = out
    assert h.kind == "health" and h.to_body()["status"] == "degraded"
    assert h.to_body()["input_status"] == "degraded" and h.to_body()["tick_status"] == "ok"
    assert "T_air_in (not_connected: no connection" in h.to_body()["detail"]
    assert svc.on_scan(T0 + 630 * S, dict(GOOD, T_air_in=None)) == []  # same state
    (h,) = svc.on_scan(T0 + 640 * S, GOOD)
    assert h.to_body()["status"] == "ok"


def test_silence_turns_health_stale_and_closes_gap_windows() -> None:
    svc = EstimatorService(FakeEstimator(), tick_delay_s=10.0, gap_after_s=60.0)
    feed(svc, (("scan", t, b) for t, b in scans(10, 650)))
    assert svc.advance(T0 + 700 * S) == []  # 50 s of silence: not yet
    (h,) = svc.advance(T0 + 720 * S)
    assert h.to_body()["status"] == "stale" and "no scans for 70 s" in h.to_body()["detail"]
    out = svc.advance(T0 + 1900 * S)
    assert ticks(out) == [1200, 1800]
    stale = [o.to_body() for o in out if o.kind == "estimate"]
    assert all(b["stale"] for b in stale) and [b["n_scans"] for b in stale] == [5, 0]
    assert svc.advance(T0 + 1900 * S) == []


def test_refused_lab_files_count_and_lab_silence_degrades_health() -> None:
    """Issue 30 item 1: a lab file the folder refused reaches the counters and the health body
    at once, and health turns degraded once no lab result was accepted for
    ``max_lab_silence_s`` (from the first scan, then from the last accepted one), naming the
    last refusal; an accepted result makes it ok again, and a checkpoint keeps the lab clock."""
    svc = EstimatorService(FakeEstimator(), tick_delay_s=0.0, max_lab_silence_s=3600.0)
    feed(svc, (("scan", t, b) for t, b in scans(10, 1200)))
    (h,) = svc.lab_file_refused("lims.csv row 2: column 'Moisture' holds no number", T0 + 1205 * S)
    assert h.kind == "health" and h.time_ns == T0 + 1205 * S
    assert h.to_body()["labs_refused"] == 1 and h.to_body()["lab_files_refused"] == 1
    assert h.last_lab_refusal == ("lab file refused: lims.csv row 2: column 'Moisture' "
                                  "holds no number")
    assert h.status == "ok" and h.lab.status == "ok"  # not silent for long yet
    out = feed(svc, (("scan", t, b) for t, b in scans(1210, 3610)))
    assert [o.to_body()["status"] for o in out if o.kind == "health"][-1] == "ok"  # 3600 s: not yet
    (h,) = svc.on_scan(T0 + 3620 * S, GOOD)  # said when it happens, not at the next tick
    assert h.to_body()["status"] == "degraded" and h.to_body()["lab_status"] == "degraded"
    out = feed(svc, (("scan", t, b) for t, b in scans(3630, 4210)))
    est, h = out[-2:]
    assert est.kind == "estimate" and est.to_body()["status"] == "ok"  # the estimator's verdict
    assert h.to_body()["status"] == "degraded" and h.to_body()["lab_status"] == "degraded"
    assert "no lab result accepted for 1.2 h since the first scan (service.max_lab_silence_h " \
           "1)" in h.to_body()["detail"]
    assert "last lab refusal: lab file refused: lims.csv row 2" in h.to_body()["detail"]
    # a checkpoint carries the lab clock and the last refusal
    again = EstimatorService(FakeEstimator(), tick_delay_s=0.0, max_lab_silence_s=3600.0)
    again.restore(json.loads(json.dumps(svc.checkpoint())))
    assert h.to_body()["detail"] in again._health(T0 + 4200 * S).to_body()["detail"]
    # an accepted result: ok again, and the silence counts from it
    out = feed(again, [("lab", T0 + 4300 * S, lab("A", 4000)),
                       *(("scan", t, b) for t, b in scans(4210, 4810))])
    assert [o.to_body()["status"] for o in out if o.kind == "health"][-1] == "ok"
    assert again.stats.labs_accepted == 1
    out = feed(again, (("scan", t, b) for t, b in scans(4820, 8500)))
    assert [o.to_body()["status"] for o in out if o.kind == "health"][-1] == "degraded"
    assert "since the last one" in out[-1].to_body()["detail"]
    # off (None): never degraded for want of labs
    quiet = EstimatorService(FakeEstimator(), tick_delay_s=0.0)
    out = feed(quiet, (("scan", t, b) for t, b in scans(10, 8000)))
    assert [o.to_body()["status"] for o in out if o.kind == "health"][-1] == "ok"
    assert {o.to_body()["lab_status"] for o in out if o.kind == "health"} == {"ok"}


# --- checkpoints ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_day():
    return simulate_day(load_plant_config(), 3.0, 5, "inlet_moisture")


def _messages(day) -> list[tuple[str, int, dict[str, Any]]]:
    msgs = [("scan", int(t), {k: (None if math.isnan(v) else v) for k, v in row.items()})
            for t, row in zip(day.scans.index, day.scans.to_dict("records"), strict=True)]
    msgs += [("lab", int(r["log_time_ns"]), {"sample_time_ns": int(r["sample_time_ns"]),
                                             "moisture_out": float(r["moisture_out"]),
                                             "sample_id": r["sample_id"]})
             for r in day.labs.to_dict("records")]
    return sorted(msgs, key=lambda m: (m[1], m[0]))


def test_a_restored_ukf_service_continues_bit_for_bit(short_day, tmp_path) -> None:
    cfg = load_plant_config()
    msgs = _messages(short_day)
    assert any(m[0] == "lab" for m in msgs)
    whole = EstimatorService(make_estimator("ukf", cfg))
    expected = feed(whole, msgs) + whole.flush()
    assert len(ticks(expected)) >= 18 and whole.stats.labs_accepted >= 1

    first = EstimatorService(make_estimator("ukf", cfg))
    cut = next(i for i, m in enumerate(msgs) if m[1] > short_day.scans.index[0] + 5400 * S)
    got = feed(first, msgs[:cut])
    store = CheckpointStore(tmp_path / "state" / "ckpt.json")
    store.save(first.checkpoint(), saved_at_ns=msgs[cut - 1][1], unit="dryer1")
    assert not store.tmp_path.exists()
    doc = store.load()
    second = EstimatorService(make_estimator("ukf", cfg))
    second.restore(doc["service"], where=str(store.path))
    got += feed(second, msgs[cut:]) + second.flush()
    assert [(o.kind, o.time_ns, o.to_body()) for o in got if o.kind == "estimate"] == \
        [(o.kind, o.time_ns, o.to_body()) for o in expected if o.kind == "estimate"]
    assert second.stats.ticks == whole.stats.ticks

    other = EstimatorService(make_estimator("openloop", cfg))
    with pytest.raises(EstimationError, match="written by estimator 'ukf'.*'openloop'"):
        other.restore(doc["service"], where=str(store.path))


def test_checkpoint_files_fail_with_one_line_naming_the_file(tmp_path) -> None:
    store = CheckpointStore(tmp_path / "ckpt.json")
    assert store.load() is None
    store.path.write_text("{not json")
    with pytest.raises(ConfigError, match=r"ckpt.json: checkpoint is not valid JSON") as e:
        store.load()
    assert "\n" not in str(e.value)
    store.path.write_text(json.dumps({"format": "softsensor-checkpoint", "version": 99}))
    with pytest.raises(ConfigError, match="version 99"):
        store.load()
    store.save({"x": 1}, saved_at_ns=5, unit="u")
    assert store.load()["service"] == {"x": 1} and store.n_saved == 1
    store.discard()
    assert store.load() is None


# --- settings, factory, logs, clock -------------------------------------------------------


def test_service_settings_defaults_and_validation(tmp_path) -> None:
    cfg = load_plant_config()
    s = service_settings(cfg)
    assert s.listen == ("tcp/127.0.0.1:7447",) and s.connect == () and s.time_scale == 1.0
    data = read_toml(cfg.source)
    for table, match in [({"bogus": 1}, r"service\.bogus is not a known key"),
                         ({"time_scale": 0}, r"service\.time_scale must be >= 0\.01"),
                         ({"zenoh_listen": ["7447"]}, r"service\.zenoh_listen entry '7447'"),
                         ({"zenoh_mode": "client"}, r"service\.zenoh_connect must name"),
                         # one key for one rule: the estimator's kind and a window's
                         # good share are set where the estimator and the windowing read them
                         ({"estimator": "ukf"}, r"service\.estimator is not a key any more: "
                                                r"set estimator\.kind"),
                         ({"min_good_fraction": 0.5}, r"service\.min_good_fraction is not a "
                                                      r"key any more: set solver\."),
                         ({"clock_start": "yesterday"}, r"clock_start must be")]:
        bad = plant_config_from_dict({**data, "service": table}, "plant.toml")
        with pytest.raises(ConfigError, match=match) as e:
            service_settings(bad)
        assert str(e.value).startswith("plant.toml: ")
    s2 = s.with_overrides(time_scale=60.0, zenoh_connect=["tcp/10.0.0.5:7447"], unit=None)
    assert s2.time_scale == 60.0 and s2.connect == ("tcp/10.0.0.5:7447",) and s2.unit is None
    with pytest.raises(ConfigError, match="command line: service.plc_port must be <= 65535"):
        s.with_overrides(plc_port=70000)
    assert ServiceSettings(zenoh_mode="client", zenoh_connect=("tcp/h:1",)).listen == ()


def test_make_estimator_kinds() -> None:
    cfg = load_plant_config()
    assert make_estimator(None, cfg).kind == "ukf"
    assert make_estimator("openloop", cfg).kind == "openloop"
    with pytest.raises(ConfigError, match="estimator 'kalman' is not known"):
        make_estimator("kalman", cfg)


def test_warm_up_ticks_a_throwaway_service_with_a_late_lab() -> None:
    """Every path of a tick runs once before streaming (full windows, a lab applied late),
    on a service of its own: the real one never sees the synthetic messages."""
    made: list[FakeEstimator] = []

    def make() -> EstimatorService:
        made.append(FakeEstimator())
        return EstimatorService(made[-1])

    warm = warm_up(make, load_plant_config())
    assert warm.error is None and len(made) == 1
    events = made[0].events
    tick_at = [i for i, e in enumerate(events) if e[0] == "tick"]
    assert len(tick_at) == N_WINDOWS and not any(events[i][2] for i in tick_at)  # none stale
    lab_at = events.index(("lab", "warm-up"))
    assert tick_at[0] < lab_at < tick_at[-1]  # after a model estimate, before the last tick
    assert warm.stats is not None and warm.stats.labs_accepted == 1


def test_a_failing_warm_up_is_logged_not_raised(caplog) -> None:
    def make() -> EstimatorService:
        raise EstimationError("model failed at the nominal point")

    with caplog.at_level(logging.WARNING, logger="softsensor.service.warmup"):
        warm = warm_up(make, load_plant_config())
    assert warm.stats is None and "model failed at the nominal point" in warm.error
    assert "warm-up failed" in caplog.text


def test_structured_log_lines() -> None:
    logger = logging.getLogger("test.service.logs")
    records: list[logging.LogRecord] = []
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    try:
        event(logger, "tick", status="ok", moisture_out=0.1, detail="two words", gone=None)
    finally:
        logger.removeHandler(handler)
    (rec,) = records
    line = KeyValueFormatter().format(rec)
    assert "\n" not in line
    assert line.split(" ", 1)[0].startswith("ts=20")
    assert ("level=info logger=test.service.logs event=tick status=ok moisture_out=0.1 "
            'detail="two words" gone=null') in line
    doc = json.loads(JsonFormatter().format(rec))
    assert doc["event"] == "tick" and doc["moisture_out"] == 0.1 and doc["gone"] is None


def test_scaled_clock() -> None:
    mono = [100.0]
    clock = ScaledClock(60.0, T0, monotonic=lambda: mono[0])
    assert clock.now_ns() == T0
    mono[0] += 10.0
    assert clock.now_ns() == T0 + 600 * S and clock.monotonic() == pytest.approx(600.0)
    wall = ScaledClock(1.0, wall_ns=lambda: 42)
    assert wall.is_wall and wall.now_ns() == 42
    with pytest.raises(ConfigError, match="time_scale"):
        ScaledClock(0.0)


def test_required_signals_are_the_model_inputs() -> None:
    assert set(WindowSettings().required) == set(MODEL_SIGNALS) <= set(SCAN_SIGNALS)


def test_a_refused_lab_result_is_told_by_its_sample_id() -> None:
    """Issue 40: the daemon's lab input frees the id of a result the estimator refused (here
    the fake's screen, and a flood beyond ``max_pending_labs``), so a corrected result with
    the same id is taken."""
    svc = EstimatorService(FakeEstimator(), tick_delay_s=30.0, max_pending_labs=2)
    freed: list[str] = []
    svc.on_lab_refused = freed.append
    feed(svc, [("lab", T0 + 100 * S, lab("ok", 50)), ("lab", T0 + 110 * S, lab("wet", 60, 0.9)),
               ("lab", T0 + 120 * S, lab("flood", 70)), *(("scan", t, b) for t, b in
                                                         scans(10, 700))])
    assert freed == ["flood", "wet"]
    assert svc.stats.labs_accepted == 1 and svc.stats.labs_refused == 2


def test_the_warm_up_lab_is_not_logged_as_an_accepted_lab(caplog) -> None:
    """Issue 40: the warm-up's made-up lab result was logged like a plant's, with a raw
    nanosecond timestamp four days before the plant clock; issue 49: then as "synthetic
    warm-up lab warm-up accepted" at INFO, beside the real ones. Now no line an operator
    reads says a lab was accepted: one DEBUG line says what the made-up result did, with a
    readable time; a real lab's line is unchanged."""
    caplog.set_level(logging.DEBUG, logger="softsensor.service.estimator_service")
    warm_up(lambda: EstimatorService(FakeEstimator()), load_plant_config())
    info = [r.getMessage() for r in caplog.records if r.levelno >= logging.INFO]
    assert not [m for m in info if "accepted" in m or "lab" in m], info
    debug = [r.getMessage() for r in caplog.records if "synthetic lab" in r.getMessage()]
    assert len(debug) == 1, debug
    assert re.fullmatch(r"warm-up: the synthetic lab result \(moisture_out 0\.1000 kg/kg, made "
                        r"up at \d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ\) compiled the lab update; not "
                        r"a plant result", debug[0]), debug
    caplog.clear()
    svc = EstimatorService(FakeEstimator())
    feed(svc, [("lab", T0 + 100 * S, lab("L1", 50)), *(("scan", t, b) for t, b in
                                                      scans(10, 700))])
    accepted = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO
                and "accepted" in r.getMessage()]
    assert len(accepted) == 1 and accepted[0].startswith("lab L1 accepted: "), accepted
