"""The estimator's worker on its two sides of a bus.

On Zenoh: the queue in front of the estimator thread is bounded in payload bytes, not only in
messages (issue 31 item 2: 10,000 queued 60 kB scans are 600 MB), and the open window keeps
a scan's signals, not what else a peer put into it (a real Zenoh pair on loopback and the real
estimator service; the worker is held busy while a peer floods). In memory: without a thread
the worker steps each message as it is put, and its limits hold as on Zenoh."""

from __future__ import annotations

import threading
import time

from softsensor.bus.memory import MemoryBus, MemoryInput, MemoryOutput
from softsensor.bus.transport import OUTPUT_KINDS, BusMessage
from softsensor.bus.zenoh_bus import (
    Publisher,
    listening_endpoints,
    open_session,
    wait_for_peers,
    zenoh_sides,
)
from softsensor.plantconfig import load_plant_config
from softsensor.service.build import make_service
from softsensor.service.bus_worker import BusWorker, InputLimits
from softsensor.service.settings import ServiceSettings

PAD = "x" * 60_000  # a 60 kB scan


def test_the_queue_holds_at_most_its_bytes_and_the_window_no_padding():
    service = make_service(load_plant_config(), ServiceSettings(), "openloop", 10.0)
    cap = 1_000_000
    with open_session(port=0) as daemon:
        pipeline = BusWorker(service, *zenoh_sides(daemon), limits=InputLimits(
            max_queue=10_000, max_queue_bytes=cap, max_bytes=65_536))
        release, held = threading.Event(), threading.Event()

        def hold() -> None:
            held.set()
            release.wait(30)

        worker = threading.Thread(target=pipeline.call, args=(hold,), daemon=True)
        worker.start()
        assert held.wait(10)
        most = 0
        try:
            with open_session(port=None, connect=listening_endpoints(daemon)) as peer:
                assert wait_for_peers(peer, timeout=10)
                pub = Publisher(peer, "dryer1")
                pub.declare(("scan",))
                time.sleep(0.3)
                t0 = 1_767_225_600 * 10**9
                for i in range(200):  # 12 MB
                    pub.put("scan", {"T_air_in": 480.0, "m_air": 82.0, "pad": PAD},
                            t0 + i * 10**9)
                    most = max(most, pipeline._pending_bytes)
                deadline = time.monotonic() + 10
                while pipeline.subscription.n_received < 200 and time.monotonic() < deadline:
                    most = max(most, pipeline._pending_bytes)
                    time.sleep(0.01)
                pub.close()
        finally:
            release.set()
            worker.join(10)
        pipeline.sync()
        assert pipeline.subscription.n_received == 200
        assert most <= cap
        queued = 200 - pipeline.dropped["queue_full"]
        assert 10 <= queued <= cap // 60_000 + 1, pipeline.dropped  # the bytes' bound
        kept = service.checkpoint()["window_scans"]
        assert kept and all("pad" not in body for _t, body in kept)
        assert all(body["T_air_in"] == 480.0 for _t, body in kept)
        pipeline.close(checkpoint=False)


def _scans(n: int, t0: int = 1_767_225_600 * 10**9) -> list[tuple[int, dict]]:
    return [(t0 + i * 10**10, {"T_air_in": 480.0, "m_air": 82.0, "m_fiber": 6.0,
                               "T_fiber_in": 370.0, "m_steam": 0.5, "T_amb": 283.0,
                               "H_amb": 0.006, "flap_cmd": 40.0, "T_sp": 348.0,
                               "T_dryer_out": 348.0, "T_cyclone_out": 346.5})
            for i in range(n)]


def test_without_a_thread_each_message_is_stepped_before_its_put_returns():
    """Behind a memory input the worker can run the service on the sender's thread: an
    estimate is on the bus before the put of the scan that closed its window returns, and
    nothing waits in a queue."""
    service = make_service(load_plant_config(), ServiceSettings(), "openloop", 10.0)
    bus = MemoryBus()
    out: list[BusMessage] = []
    bus.subscribe(out.append, OUTPUT_KINDS)
    worker = BusWorker(service, MemoryInput(bus), MemoryOutput(bus), thread=False)
    first_estimate = None
    for i, (t, body) in enumerate(_scans(200)):
        bus.put("scan", body, t)
        assert worker.pending == 0
        if first_estimate is None and any(m.kind == "estimate" for m in out):
            first_estimate = i
    assert first_estimate is not None and worker.n_in == 200
    n_estimates = sum(m.kind == "estimate" for m in out)
    assert n_estimates == service.stats.ticks >= 2
    worker.flush()  # at once: nothing is queued
    assert sum(m.kind == "estimate" for m in out) == service.stats.ticks > n_estimates
    assert worker.call(lambda: threading.current_thread()) is threading.current_thread()
    worker.close(checkpoint=False)
    bus.put("scan", _scans(1, t)[0][1], t + 10**10)  # closed: no longer received
    assert worker.n_in == 200


def test_the_limits_hold_behind_a_memory_input():
    """The worker's limits apply whatever the input side: a message over ``max_bytes`` is
    refused before it is handed over, a source over its rate is dropped, a message that would
    take the queue over its bytes is dropped (the memory side measures it for that), all
    counted."""
    service = make_service(load_plant_config(), ServiceSettings(), "openloop", 10.0)
    bus = MemoryBus()
    worker = BusWorker(service, MemoryInput(bus), MemoryOutput(bus), thread=False,
                       limits=InputLimits(max_bytes=2_000, rates_per_s={"lab": 1e-6},
                                          burst=2.0))
    scans = _scans(3)
    bus.put("scan", scans[0][1], scans[0][0])
    bus.put("scan", {**scans[1][1], "pad": PAD}, scans[1][0])
    for i in range(5):
        bus.put("lab", {"sample_time_ns": scans[0][0], "moisture_out": 0.1,
                        "sample_id": f"L{i}"}, scans[2][0])
    assert worker.dropped == {"queue_full": 0, "rate": 3, "too_large": 1, "shutdown": 0,
                              "other_sender": 0}
    assert worker.n_in == 3 and worker.n_labs_received == 5 and service.stats.scans == 1
    worker.close(checkpoint=False)

    small = BusWorker(service, MemoryInput(bus), MemoryOutput(bus), thread=False,
                      limits=InputLimits(max_queue_bytes=100))
    bus.put("scan", scans[2][1], scans[2][0])  # about 250 bytes as a payload
    assert small.dropped["queue_full"] == 1 and small.n_in == 0
    small.close(checkpoint=False)
