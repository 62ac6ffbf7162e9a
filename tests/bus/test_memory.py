"""The in-process bus: what one thread puts reaches every subscriber of its kind, in order,
before ``put`` returns, shaped as a Zenoh payload decodes (``time_ns`` in the body)."""

from __future__ import annotations

import pytest

from softsensor.bus.memory import MemoryBus, MemoryInput, MemoryOutput
from softsensor.bus.transport import KINDS, BusMessage, encode_payload

T0 = 1_750_000_000 * 10**9
SCAN = {"T_air_in": 452.1, "m_air": 82.0, "T_amb": None}


def test_every_subscriber_has_each_message_in_order_before_put_returns() -> None:
    bus = MemoryBus("u3")
    first: list[BusMessage] = []
    second: list[BusMessage] = []
    bus.subscribe(first.append)
    bus.subscribe(second.append, ("scan",))
    seen_at_put = []
    for i in range(50):
        kind = "lab" if i % 10 == 5 else "scan"
        bus.put(kind, {"i": i}, T0 + i)
        seen_at_put.append(len(first))
    assert seen_at_put == list(range(1, 51))  # delivered within put, no queue
    assert [m.body["i"] for m in first] == list(range(50))
    assert [m.body["i"] for m in second] == [i for i in range(50) if i % 10 != 5]
    m = first[5]
    assert (m.kind, m.key, m.time_ns, m.topic) == ("lab", "plant/u3/lab", T0 + 5, "/plant/lab")
    assert m.body == {"i": 5, "time_ns": T0 + 5}  # as a Zenoh payload decodes
    assert bus.n_published == 50


def test_each_subscriber_has_its_own_body_and_the_sender_keeps_its_own() -> None:
    bus = MemoryBus()
    a: list[BusMessage] = []
    b: list[BusMessage] = []
    bus.subscribe(a.append)
    bus.subscribe(b.append)
    sent = dict(SCAN)
    bus.put("scan", sent, T0)
    a[0].body.pop("T_air_in")
    assert b[0].body == {**SCAN, "time_ns": T0}
    assert sent == SCAN  # no time_ns added to the sender's dict


def test_sizes_are_measured_when_asked_and_max_bytes_refuses_before_delivery() -> None:
    bus = MemoryBus()
    plain: list[BusMessage] = []
    sized: list[BusMessage] = []
    bounded: list[BusMessage] = []
    too_large = []
    bus.subscribe(plain.append)
    bus.subscribe(sized.append, sized=True)
    limit = len(encode_payload(SCAN, T0))
    sub = bus.subscribe(bounded.append, max_bytes=limit,
                        on_too_large=lambda: too_large.append(1))
    bus.put("scan", SCAN, T0)
    bus.put("scan", {**SCAN, "pad": "x"}, T0 + 1)
    assert [m.nbytes for m in plain] == [0, 0]  # not measured: an encoding per message
    assert [m.nbytes for m in sized] == [limit, len(encode_payload({**SCAN, "pad": "x"}, T0))]
    assert [m.time_ns for m in bounded] == [T0] and too_large == [1]
    assert bounded[0].nbytes == limit and sub.n_received == 1


def test_the_worker_sides_carry_inputs_in_and_outputs_out() -> None:
    bus = MemoryBus()
    everything: list[BusMessage] = []
    bus.subscribe(everything.append)
    inputs: list[BusMessage] = []
    side = MemoryInput(bus)
    side.open(inputs.append)
    with pytest.raises(RuntimeError, match="open already"):
        side.open(inputs.append)
    out = MemoryOutput(bus)
    for kind in KINDS:
        bus.put(kind, {"k": kind}, T0)
    out.put("estimate", {"moisture_out": 0.1}, T0 + 1)
    assert [m.kind for m in inputs] == ["scan", "lab"] and side.n_received == 2
    assert [m.kind for m in everything] == [*KINDS, "estimate"]
    assert everything[-1].body == {"moisture_out": 0.1, "time_ns": T0 + 1}
    side.close()
    side.close()  # idempotent
    bus.put("scan", {}, T0 + 2)
    assert side.n_received == 2 and len(everything) == 6
    out.close()
    with pytest.raises(RuntimeError, match="closed output"):
        out.put("health", {"status": "ok"}, T0 + 3)


def test_a_failing_subscriber_reaches_the_sender_and_no_time_is_the_clock() -> None:
    bus = MemoryBus(clock=lambda: T0 + 42)
    got: list[BusMessage] = []
    bus.subscribe(got.append)

    def boom(_m: BusMessage) -> None:
        raise ValueError("disk full")

    with bus.subscribe(boom, ("lab",)):
        with pytest.raises(ValueError, match="disk full"):
            bus.put("lab", {"sample_id": "L1"})
    bus.put("lab", {"sample_id": "L2"})  # unsubscribed by the with block
    assert [m.time_ns for m in got] == [T0 + 42, T0 + 42]
