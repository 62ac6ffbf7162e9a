"""The queue in front of the estimator thread is bounded in payload bytes, not only in
messages (issue 31 item 2: 10,000 queued 60 kB scans are 600 MB), and the open window keeps
a scan's signals, not what else a peer put into it. A real Zenoh pair on loopback and the real
estimator service; the worker is held busy while a peer floods."""

from __future__ import annotations

import threading
import time

from softsensor.bus.zenoh_bus import Publisher, listening_endpoints, open_session, wait_for_peers
from softsensor.plantconfig import load_plant_config
from softsensor.service.build import make_service
from softsensor.service.bus_worker import InputLimits, ServicePipeline
from softsensor.service.settings import ServiceSettings

PAD = "x" * 60_000  # a 60 kB scan


def test_the_queue_holds_at_most_its_bytes_and_the_window_no_padding():
    service = make_service(load_plant_config(), ServiceSettings(), "openloop", 10.0)
    cap = 1_000_000
    with open_session(port=0) as daemon:
        pipeline = ServicePipeline(daemon, service, limits=InputLimits(
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
