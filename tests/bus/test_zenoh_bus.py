"""The Zenoh bus on loopback: two sessions, scouting off, every key kind round-trips."""

from __future__ import annotations

import asyncio
import json
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Iterator

import pytest
import zenoh

from softsensor.bus.transport import KIND_TOPIC, KINDS, BusMessage, encode_payload
from softsensor.bus.zenoh_bus import (
    Publisher,
    Subscription,
    decode_payload,
    kind_of_key,
    listening_endpoints,
    make_config,
    open_session,
    subscribe,
    to_message,
    wait_for_peers,
)
from softsensor.errors import ConfigError, IngestError
from softsensor.log_throttle import outside_text

DEADLINE = 5.0  # [s] for anything on loopback
log = logging.getLogger(__name__)

BODIES = {
    "scan": {"T_air_in": 452.1, "m_air": 82.0, "T_amb": None},
    "lab": {"sample_time_ns": 1_750_000_000 * 10**9, "moisture_out": 0.1, "sample_id": "L1"},
    "estimate": {"moisture_out": 0.1, "moisture_out_std": 0.01, "moisture_in": 1.0,
                 "moisture_in_std": 0.05, "T_dryer_out_model": 348.0,
                 "T_cyclone_out_model": 345.0, "lab_updated": False},
    "health": {"status": "ok", "detail": "all good"},
}


def _wait(cond, timeout: float = DEADLINE) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


@pytest.fixture
def pair() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    with open_session(port=0) as a:
        (endpoint,) = listening_endpoints(a)
        assert endpoint.startswith("tcp/127.0.0.1:")
        with open_session(port=0, connect=[endpoint]) as b:
            assert wait_for_peers(a, timeout=DEADLINE) and wait_for_peers(b, timeout=DEADLINE)
            yield a, b


# --- pure parts ---------------------------------------------------------------------------


def test_config_is_explicit() -> None:
    cfg = make_config(port=7447)
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    cfg = make_config(mode="client", connect=["tcp/127.0.0.1:7447"])
    assert json.loads(cfg.get_json("listen/endpoints")) == []
    assert json.loads(cfg.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]


@pytest.mark.parametrize("kwargs, match", [
    ({"mode": "bridge"}, "bus.mode"),
    ({"mode": "client"}, "bus.connect"),
    ({"port": 70000}, "bus.port"),
    ({"connect": ["127.0.0.1:7447"]}, "endpoint"),
])
def test_config_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make_config(**kwargs)


def test_payload_codec() -> None:
    data = encode_payload({"a": math.nan, "b": 1.5}, 42)
    assert json.loads(data) == {"a": None, "b": 1.5, "time_ns": 42}
    assert decode_payload(data) == {"a": None, "b": 1.5, "time_ns": 42}
    with pytest.raises(IngestError, match="plant/dryer1/scan: payload is not valid JSON"):
        decode_payload(b"{", "plant/dryer1/scan")
    with pytest.raises(IngestError, match="not an object"):
        decode_payload(b"[1]")
    msg = to_message("softsensor/u2/health", data, unit="u2")
    assert msg.kind == "health" and msg.time_ns == 42 and msg.topic == "/softsensor/health"
    assert kind_of_key("plant/dryer1/lab") == "lab"
    with pytest.raises(IngestError, match="plant/other/scan"):
        kind_of_key("plant/other/scan")
    with pytest.raises(IngestError, match="time_ns"):
        to_message("plant/dryer1/scan", b'{"time_ns": "now"}')


def test_port_taken_is_a_config_error() -> None:
    with open_session(port=0) as a:
        (endpoint,) = listening_endpoints(a)
        port = int(endpoint.rsplit(":", 1)[1])
        with pytest.raises(ConfigError, match="zenoh session could not open"):
            open_session(port=port)


# --- two sessions ---------------------------------------------------------------------------


def test_round_trip_every_kind(pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    a, b = pair
    got: list[BusMessage] = []
    lock = threading.Lock()

    def on_msg(m: BusMessage) -> None:
        with lock:
            got.append(m)

    with subscribe(a, on_msg, unit="dryer1") as sub, Publisher(b, unit="dryer1") as pub:
        assert pub.wait_matched(KINDS, timeout=DEADLINE)
        for i, kind in enumerate(KINDS):
            pub.put(kind, BODIES[kind], time_ns=1000 + i)
        assert _wait(lambda: len(got) == len(KINDS))
        assert sub.n_received == len(KINDS) and sub.n_errors == 0
    by_kind = {m.kind: m for m in got}
    for i, kind in enumerate(KINDS):
        m = by_kind[kind]
        assert m.key == f"{'plant' if kind in ('scan', 'lab') else 'softsensor'}/dryer1/{kind}"
        assert m.body == {**BODIES[kind], "time_ns": 1000 + i}
        assert m.time_ns == 1000 + i
        assert m.topic == KIND_TOPIC[kind]


def test_wall_clock_time_and_other_unit_ignored(pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    a, b = pair
    got: list[BusMessage] = []
    with subscribe(a, got.append, kinds=["health"]), \
            Publisher(b, clock=lambda: 777) as pub, Publisher(b, unit="dryer2") as other:
        assert pub.wait_matched(["health"], timeout=DEADLINE)
        other.put("health", BODIES["health"])
        pub.put("health", BODIES["health"])
        assert _wait(lambda: len(got) >= 1)
        time.sleep(0.05)
    assert [m.time_ns for m in got] == [777]


def test_malformed_payload_and_failing_callback(
        pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    a, b = pair
    errors: list[tuple[str, str]] = []

    def boom(m: BusMessage) -> None:
        if m.body.get("boom"):
            raise RuntimeError("kaputt")

    with subscribe(a, boom, kinds=["scan"], on_error=lambda k, e: errors.append((k, e))) as sub, \
            Publisher(b) as pub:
        assert pub.wait_matched(["scan"], timeout=DEADLINE)
        b.put("plant/dryer1/scan", b"not json")
        pub.put("scan", {"boom": True})
        pub.put("scan", {"T_amb": 280.0})
        assert _wait(lambda: sub.n_errors == 2 and sub.n_received == 1)
    assert errors[0] == ("plant/dryer1/scan", "plant/dryer1/scan: payload is not valid JSON")
    assert "kaputt" in errors[1][1]


def subscribe_queue(session: zenoh.Session, loop: asyncio.AbstractEventLoop,
                    queue: asyncio.Queue[BusMessage], *, unit: str = "dryer1",
                    kinds: Iterable[str] = KINDS,
                    on_error: Callable[[str, str], None] | None = None) -> Subscription:
    """Put decoded messages of ``kinds`` into an asyncio ``queue`` running on ``loop`` (a
    test's way to await bus messages; the program's consumers hand them to a thread).

    The hand-off uses ``loop.call_soon_threadsafe``; when a bounded queue is full the message
    is dropped and counted as an error (Zenoh's thread never blocks on the event loop).
    """
    holder: list[Subscription] = []

    def _put(message: BusMessage) -> None:
        try:
            queue.put_nowait(message)
        except asyncio.QueueFull:
            if holder:
                holder[0]._count(False)
                holder[0].throttle.log(log, "queue full", logging.WARNING,
                                       "%s: asyncio queue full, message dropped",
                                       outside_text(message.key))

    def _callback(message: BusMessage) -> None:
        if loop.is_closed():
            raise RuntimeError("event loop is closed")
        loop.call_soon_threadsafe(_put, message)

    sub = subscribe(session, _callback, unit=unit, kinds=kinds, on_error=on_error)
    holder.append(sub)
    return sub



def test_asyncio_queue(pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    a, b = pair

    async def main() -> list[BusMessage]:
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[BusMessage] = asyncio.Queue()
        with subscribe_queue(a, loop, queue), Publisher(b) as pub:
            assert pub.wait_matched(timeout=DEADLINE)
            for i in range(200):
                pub.put("scan", {"T_amb": 270.0 + i}, time_ns=i)
            return [await asyncio.wait_for(queue.get(), DEADLINE) for _ in range(200)]

    got = asyncio.run(main())
    assert [m.time_ns for m in got] == list(range(200))


def test_asyncio_bounded_queue_drops_not_blocks(pair: tuple[zenoh.Session, zenoh.Session]) -> None:
    a, b = pair

    async def main() -> tuple[int, int]:
        loop = asyncio.get_running_loop()
        queue: asyncio.Queue[BusMessage] = asyncio.Queue(maxsize=5)
        with subscribe_queue(a, loop, queue, kinds=["scan"]) as sub, Publisher(b) as pub:
            assert pub.wait_matched(["scan"], timeout=DEADLINE)
            for i in range(50):
                pub.put("scan", {"T_amb": 270.0}, time_ns=i)
            deadline = loop.time() + DEADLINE
            while sub.n_received < 50 and loop.time() < deadline:
                await asyncio.sleep(0.01)
            await asyncio.sleep(0.05)
            return queue.qsize(), sub.n_errors

    size, dropped = asyncio.run(main())
    assert size == 5 and dropped == 45


def test_client_through_router() -> None:
    """A Python session in router mode stands in for zenohd between two clients."""
    with open_session(mode="router", port=0) as router:
        (endpoint,) = listening_endpoints(router)
        with open_session(mode="client", connect=[endpoint]) as c1, \
                open_session(mode="client", connect=[endpoint]) as c2:
            assert wait_for_peers(c1, routers=True, timeout=DEADLINE)
            got: list[BusMessage] = []
            with subscribe(c1, got.append, kinds=["estimate"]), Publisher(c2) as pub:
                assert pub.wait_matched(["estimate"], timeout=DEADLINE)
                pub.put("estimate", BODIES["estimate"], time_ns=5)
                assert _wait(lambda: len(got) == 1)
    assert got[0].body["lab_updated"] is False


def test_client_without_router_fails_cleanly() -> None:
    from softsensor.bus.zenoh_bus import free_port

    with pytest.raises(ConfigError, match="could not open"):
        open_session(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"])
