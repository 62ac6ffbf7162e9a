"""The scan path PLC -> poller -> Zenoh -> recorder -> MCAP, for every data type and order.

The poller's own tests check the register decoding; here the decoded values must survive the
daemon's publishing (:class:`ScanPublisher`), a Zenoh link on loopback and the recorder, and
come out of the day file in SI units. Every test has a deadline.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest

from softsensor.bus.zenoh_bus import (
    Publisher,
    ZenohInput,
    listening_endpoints,
    open_session,
    subscribe,
    wait_for_peers,
)
from softsensor.ingest.modbus_poller import ModbusPoller
from softsensor.ingest.registers import resolution
from softsensor.ingest.tagmap import TagMap, load_tagmap, parse_tagmap
from softsensor.plant.plc_server import NOMINAL_VALUES, PlcServer, constant_values
from softsensor.recording.mcap_day import read_day
from softsensor.recording.recorder import Recorder
from softsensor.service.bus_recorder import BusRecorder
from softsensor.service.scan_publisher import ScanPublisher

DEADLINE = 10.0
FAST = {"poll_period_s": 0.05, "timeout_s": 0.3, "retries": 0, "reconnect_delay_s": 0.05,
        "reconnect_delay_max_s": 0.2, "frozen_after_s": 3600.0}
VALUES = {"T_air_in": 512.34, "T_sp": 348.15, "T_amb": 268.0, "T_dryer_out": 348.0,
          "m_air": 82.5, "m_fiber": 6.1, "m_steam": 0.512, "H_amb": 0.0081,
          "T_cyclone_out": 338.2, "T_fiber_in": 371.3, "flap_cmd": 41.7}


def every_type_map(word: str, byte: str) -> TagMap:
    """Each data type of the register codecs once, in one word and byte order."""
    def tag(unit_id, table, address, dtype, unit, scale=1.0, offset=0.0):
        return {"unit_id": unit_id, "table": table, "address": address, "type": dtype,
                "word_order": word, "byte_order": byte, "scale": scale, "offset": offset,
                "unit": unit, "valid_min": -1e6, "valid_max": 1e6}

    tags = {
        "T_air_in": tag(1, "input", 0, "float32", "degC"),
        "T_sp": tag(1, "input", 2, "float64", "K"),
        "T_amb": tag(1, "input", 8, "int16", "degC", 0.1),
        "T_dryer_out": tag(1, "input", 9, "int32", "degF", 0.01, 300.0),
        "m_air": tag(1, "holding", 0, "int32", "kg/h"),
        "m_fiber": tag(1, "holding", 2, "uint16", "t/h", 0.01),
        "m_steam": tag(2, "holding", 40, "int16", "kg/s", 0.001),
        "H_amb": tag(2, "input", 7, "uint32", "g/kg", 0.001),
        "T_cyclone_out": tag(2, "input", 20, "float64", "degF"),
        "T_fiber_in": tag(2, "input", 30, "float32", "degF"),
        "flap_cmd": tag(1, "holding", 10, "uint16", "%", 0.1),
    }
    return parse_tagmap({"modbus": {"host": "127.0.0.1", "port": 1}, "tags": tags}, "test")


def _wait(cond, what: str) -> None:
    deadline = time.monotonic() + DEADLINE
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


async def _through_the_bus(tm: TagMap, values: dict[str, float], folder: Path, n: int = 3):
    async with PlcServer(tm, constant_values(values)) as plc:
        tm = tm.with_endpoint("127.0.0.1", plc.port).with_settings(**FAST)
        with open_session(port=0) as daemon_session:
            endpoint = listening_endpoints(daemon_session)
            with open_session(port=None, connect=endpoint) as outside:
                assert wait_for_peers(outside, timeout=DEADLINE)
                seen = []
                sub = subscribe(outside, seen.append, kinds=("scan",))
                with Recorder(folder, "dryer1") as rec:
                    bus = BusRecorder(daemon_session, rec)
                    pub = Publisher(daemon_session)
                    pub.declare(("scan",))
                    assert await asyncio.to_thread(pub.wait_matched, ("scan",), DEADLINE)
                    poller = ModbusPoller(tm, ScanPublisher(pub))
                    for _ in range(n):
                        scan = await poller.scan_once()
                        await poller.sink(*scan)
                    poller.close()
                    await asyncio.to_thread(
                        _wait, lambda: len(seen) >= n and bus.n_received >= n, "the scans")
                    bus.close()
                    pub.close()
                    paths = list(rec.paths)
                sub.close()
        return plc.write_requests, seen, paths


def _assert_si(body: dict, tm: TagMap, values: dict[str, float]) -> None:
    for sig, si in values.items():
        assert body[sig] is not None, sig
        assert abs(body[sig] - si) <= resolution(tm.tag(sig), si), (sig, body[sig], si)


@pytest.mark.parametrize(("word", "byte"), [("big", "big"), ("little", "big"),
                                            ("big", "little"), ("little", "little")])
def test_every_type_and_order_arrives_on_zenoh_and_in_the_mcap(tmp_path, word, byte) -> None:
    tm = every_type_map(word, byte)
    writes, seen, paths = asyncio.run(asyncio.wait_for(
        _through_the_bus(tm, VALUES, tmp_path), 3 * DEADLINE))
    assert writes == 0
    assert len(seen) == 3
    for msg in seen:
        assert "quality" not in msg.body and isinstance(msg.time_ns, int)
        _assert_si(msg.body, tm, VALUES)
    (path,) = paths
    day = read_day(path)
    assert len(day.scans) == 3
    for _, row in day.scans.iterrows():
        _assert_si(row.to_dict(), tm, VALUES)
    assert day.scans.index.tolist() == [m.time_ns for m in seen]


def test_the_reference_tag_map_arrives_in_si_and_bad_values_carry_their_reason(tmp_path):
    tm = load_tagmap()
    values = dict(NOMINAL_VALUES, T_dryer_out=500.0)  # above its valid_max of 450 K
    writes, seen, paths = asyncio.run(asyncio.wait_for(
        _through_the_bus(tm, values, tmp_path, n=2), 3 * DEADLINE))
    assert writes == 0
    good = {k: v for k, v in values.items() if k != "T_dryer_out"}
    for msg in seen:
        _assert_si(msg.body, tm, good)
        assert msg.body["T_dryer_out"] is None
        assert msg.body["quality"]["T_dryer_out"].startswith("out_of_range:")
    day = read_day(paths[0])
    assert day.scans["T_dryer_out"].isna().all()
    _assert_si(day.scans.iloc[0].to_dict(), tm, good)
    (_, body), _ = day.topic("/plant/scan")
    assert body["quality"] == {"T_dryer_out": seen[0].body["quality"]["T_dryer_out"]}


def test_the_service_input_keeps_one_sources_order_across_keys() -> None:
    """Scans and lab results put from one session arrive in put order (one subscriber):
    with a subscriber per key, Zenoh's threads let lab results overtake or lag the scans."""
    sent = []
    for i in range(3000):
        t = 1_767_571_200 * 10**9 + i * 10**10
        if i % 150 == 75:
            sent.append(("lab", t, {"sample_time_ns": t - 10**12, "moisture_out": 0.1,
                                    "sample_id": f"L{i}"}))
        else:
            sent.append(("scan", t, {"T_air_in": 480.0 + i % 7}))
    got = []
    with open_session(port=0) as rx:
        endpoint = listening_endpoints(rx)
        with open_session(port=None, connect=endpoint) as tx:
            assert wait_for_peers(tx, timeout=DEADLINE)
            sub = ZenohInput(rx, "dryer1")
            sub.open(got.append)
            with Publisher(tx) as pub:
                assert pub.wait_matched(("scan", "lab"), timeout=DEADLINE)
                for kind, t, body in sent:
                    pub.put(kind, body, t)
                _wait(lambda: len(got) >= len(sent), "every message")
            sub.close()
    assert [(m.kind, m.time_ns) for m in got] == [(k, t) for k, t, _ in sent]
    assert sub.n_errors == 0 and sub.n_received == len(sent)


def test_a_failing_advance_is_counted_and_the_worker_goes_on():
    """advance() has no caller waiting on it: its failure is counted and logged, and the
    next call is still served."""
    from softsensor.bus.zenoh_bus import zenoh_sides
    from softsensor.service.bus_worker import BusWorker

    class Failing:
        calls = 0

        def advance(self, now_ns):
            Failing.calls += 1
            raise RuntimeError("estimator broke")

    with open_session(port=None) as session:
        pipe = BusWorker(Failing(), *zenoh_sides(session))  # type: ignore[arg-type]
        try:
            pipe.advance(1)
            pipe.advance(2)
            pipe.sync(timeout=10.0)
            assert Failing.calls == 2 and pipe.n_errors == 2 and pipe.n_out == 0
        finally:
            pipe.close()


def test_one_message_at_a_time_reaches_the_outputs_whoever_publishes():
    """The daemon's watchdog and recorder news used to be published from the event loop's
    thread while the worker published the estimator's: the outputs (Modbus, OPC UA, the page,
    the health answer) were fed by two threads at once, and could end on the older state.
    Now both go through the pipeline's one path (publish_aside), one message at a time; and
    not through the worker's queue, since the watchdog speaks when the worker is stuck."""
    import threading

    from softsensor.bus.zenoh_bus import zenoh_sides
    from softsensor.estimate import Health
    from softsensor.service.bus_worker import BusWorker, _Call
    from softsensor.service.estimator_service import Output

    inside, most, seen = [0], [0], []
    lock = threading.Lock()

    def hook(out: Output) -> None:
        with lock:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        time.sleep(0.001)  # long enough for the other thread to come in, were it let
        seen.append(out.time_ns)
        with lock:
            inside[0] -= 1

    class Talking:
        def advance(self, now_ns):
            return [Health.from_body({"status": "ok"}, now_ns)]

    stuck = threading.Event()
    with open_session(port=None) as session:
        pipe = BusWorker(Talking(), *zenoh_sides(session),  # type: ignore[arg-type]
                         on_output=hook)
        try:
            for k in range(200):
                pipe.advance(k)
            for k in range(200):
                assert pipe.publish_aside(Health.from_body({"status": "stale"}, -k))
            pipe.sync(timeout=DEADLINE)
            assert most[0] == 1 and len(seen) == 400, (most, len(seen))
            # a worker stuck inside the estimator does not silence the aside path
            pipe._q.put(_Call(lambda: stuck.wait(30)))
            t0 = time.monotonic()
            assert pipe.publish_aside(Health.from_body({"status": "stale"}, -999))
            # at once, not after the stuck call's 30 s (the margin is for a loaded machine)
            assert seen[-1] == -999 and time.monotonic() - t0 < 10.0
        finally:
            stuck.set()
            pipe.close()
