"""Record the Zenoh bus into daily MCAP files: the bridge between :mod:`softsensor.bus` and
:mod:`softsensor.recording`, which do not know each other.

:class:`BusRecorder` subscribes to the four CONTRACT keys of a unit and records each message
under its MCAP topic (``plant/<unit>/scan`` -> ``/plant/scan``, ...) with ``time_ns`` as the
log time. ``python -m softsensor.service.bus_recorder --dir D --connect tcp/127.0.0.1:7447``
runs one until SIGTERM or SIGINT, then closes its files cleanly.

In the daemon the recorder keeps to the estimator's input limits (issue 31 item 1: a peer's
60 kB scans, 1,171 of 1,294 dropped by the rate limiter, were all recorded, 35 MB in 10 s): it
subscribes to the outputs only, and the inputs reach it from the worker once admitted
(:meth:`BusRecorder.record`); what the limits drop is recorded as counts in health
(``inputs_dropped``), not as bodies. And however the peers share those limits, each topic
grows a day file by at most ``max_topic_bytes_per_day``: beyond it messages of that topic are
counted (:attr:`BusRecorder.capped`), not recorded, until the next day. The daemon's own PLC
scans have a cap of their own (:data:`PLC_BUDGET`), so a flood from another sender cannot stop
the recording of the real scans (issue 40).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence

import zenoh

from softsensor.bus.memory import MemoryBus, MemorySubscription
from softsensor.bus.transport import KINDS, BusMessage
from softsensor.bus.zenoh_bus import Subscription, open_session, subscribe
from softsensor.errors import SoftsensorError
from softsensor.jsonable import dumps
from softsensor.log_throttle import Throttle
from softsensor.recording.recorder import RECORDER_CHUNK_SIZE, Recorder
from softsensor.service.plc_scans import OTHER, PLC
from softsensor.service.time_gate import TimeGate

log = logging.getLogger(__name__)


#: The name the PLC's own scans are capped under (and named by in health when they are).
PLC_BUDGET = "/plant/scan from the PLC"


class BusRecorder:
    """Records the CONTRACT keys of ``unit`` from a bus into a :class:`Recorder`: a Zenoh
    session, or a :class:`~softsensor.bus.memory.MemoryBus` (``replay``; its own unit).

    Each message is written under its MCAP topic with its ``time_ns`` as the log time (the
    receive time when absent), ``time_ns`` itself removed from the body. A background thread
    calls :meth:`Recorder.tick` every ``tick_s`` seconds so idle chunks are written too.
    :meth:`close` undeclares the subscribers and stops the thread; it does not close the
    recorder or the session.

    ``kinds`` are subscribed to; others may be handed to :meth:`record` (the daemon's admitted
    inputs). ``max_topic_bytes_per_day`` bounds each topic's JSON bytes per UTC day of the day
    file (None: no bound).
    """

    def __init__(self, session: zenoh.Session | MemoryBus, recorder: Recorder, *,
                 unit: str = "dryer1",
                 kinds: Iterable[str] = KINDS, tick_s: float = 1.0,
                 gate: Callable[[int], str | None] | None = None,
                 max_topic_bytes_per_day: int | None = None) -> None:
        self.recorder = recorder
        self.max_topic_bytes_per_day = max_topic_bytes_per_day
        self.capped: dict[str, int] = {}  #: messages not recorded today, per topic (the cap)
        self._day = -1
        self._day_bytes: dict[str, int] = {}
        self._count_lock = threading.Lock()  # Zenoh's threads and the worker's record
        # messages stamped impossibly (before 2000; far from the daemon's clock when it has
        # one) are not recorded: a day file named by a peer's bad clock, or a chunk broken by
        # a negative time, would lose what is real
        self.gate = gate or TimeGate(None)
        self.refused = 0
        self._stop = threading.Event()
        self.subscription: Subscription | MemorySubscription = (
            session.subscribe(self._on_message, kinds) if isinstance(session, MemoryBus)
            else subscribe(session, self._on_message, unit=unit, kinds=kinds))
        self._ticker = threading.Thread(target=self._tick_loop, args=(tick_s,),
                                        name="recorder-tick", daemon=True)
        self._ticker.start()

    def record(self, message: BusMessage, origin: str = OTHER) -> None:
        """Record ``message`` as if it had come on the bus (the worker's admitted inputs); the
        PLC's own scans (``origin`` :data:`~softsensor.service.plc_scans.PLC`) count against a
        cap of their own, so no other sender can spend it."""
        self._on_message(message, PLC_BUDGET if origin == PLC else None)

    def _within_cap(self, topic: str, file_ns: int, body: dict) -> bool:
        """Count ``body`` against ``topic``'s bytes of the day of ``file_ns``; False when the
        day's cap is spent (the message is then counted in :attr:`capped`)."""
        cap = self.max_topic_bytes_per_day
        if cap is None:
            return True
        size = len(dumps(body))
        with self._count_lock:
            day = file_ns // (86_400 * 10**9)
            if day != self._day:
                self._day, self._day_bytes, self.capped = day, {}, {}
            used = self._day_bytes.get(topic, 0)
            if used + size > cap:
                first = topic not in self.capped
                self.capped[topic] = self.capped.get(topic, 0) + 1
            else:
                self._day_bytes[topic] = used + size
                return True
        if first:
            log.warning("%s: %d bytes recorded today, the day's cap "
                        "(service.record_topic_bytes_per_day): the rest of the day is counted, "
                        "not recorded", topic, used)
        return False

    def _on_message(self, message: BusMessage, budget: str | None = None) -> None:
        body = dict(message.body)
        body.pop("time_ns", None)
        t = message.time_ns if message.time_ns is not None else time.time_ns()
        reason = self.gate(t)
        if reason is not None:
            self.refused += 1
            if self.refused % 1000 == 1:
                log.warning("%s at %d ns not recorded: %s", message.topic, t, reason)
            return
        # the day file is the daemon clock's day (when it has a clock): a peer's time, even
        # one the gate lets through (minutes ahead at midnight), never opens a file
        clock = getattr(self.gate, "clock", None)
        file_ns = t if clock is None else clock()
        if not self._within_cap(budget or message.topic, file_ns, body):
            return
        if clock is None:
            self.recorder.write(message.topic, t, body)
        else:
            self.recorder.write(message.topic, t, body, file_time_ns=file_ns)

    def _tick_loop(self, tick_s: float) -> None:
        throttle = Throttle()
        while not self._stop.wait(tick_s):
            try:
                self.recorder.tick()
            except Exception:  # noqa: BLE001 - keep the ticker alive, report it
                throttle.log(log, "tick", logging.ERROR, "recorder tick failed", exc_info=True)

    @property
    def n_received(self) -> int:
        return self.subscription.n_received

    def close(self) -> None:
        """Stop recording (idempotent)."""
        self.subscription.close()  # (what the worker hands on after this is still written)
        self._stop.set()
        self._ticker.join(timeout=5.0)

    def __enter__(self) -> BusRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def stop_on_signals(stop: threading.Event,
                    signums: Sequence[int] = (signal.SIGTERM, signal.SIGINT)) -> None:
    """Make ``signums`` set ``stop`` (main thread only); the main loop then shuts down."""
    def _handler(signum: int, _frame: object) -> None:
        log.info("signal %d: stopping", signum)
        stop.set()

    for signum in signums:
        signal.signal(signum, _handler)


def run(directory: str | os.PathLike[str], *, unit: str = "dryer1",
        connect: Sequence[str] = (), port: int | None = None, mode: str = "peer",
        stop: threading.Event | None = None, chunk_size: int = RECORDER_CHUNK_SIZE,
        flush_interval_s: float = 30.0, ready: Callable[[], None] | None = None) -> int:
    """Record the bus into ``directory`` until ``stop`` is set; return messages written."""
    stop = stop or threading.Event()
    with open_session(mode=mode, port=port, connect=connect) as session, \
            Recorder(directory, unit, chunk_size=chunk_size,
                     flush_interval_s=flush_interval_s) as recorder, \
            BusRecorder(session, recorder, unit=unit):
        if ready is not None:
            ready()
        while not stop.wait(0.2):
            pass
        return recorder.n_written


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m softsensor.service.bus_recorder``: record a unit's keys until SIGTERM/SIGINT."""
    p = argparse.ArgumentParser(prog="softsensor-recorder", description=main.__doc__)
    p.add_argument("--dir", required=True, help="folder of the day files")
    p.add_argument("--unit", default="dryer1")
    p.add_argument("--connect", action="append", default=[], help="endpoint, repeatable")
    p.add_argument("--port", type=int, default=None, help="listen on 127.0.0.1:PORT")
    p.add_argument("--mode", default="peer", choices=("peer", "client"))
    p.add_argument("--chunk-size", type=int, default=RECORDER_CHUNK_SIZE)
    p.add_argument("--flush-interval", type=float, default=30.0, help="[s]")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        n = run(args.dir, unit=args.unit, connect=args.connect, port=args.port, mode=args.mode,
                stop=stop, chunk_size=args.chunk_size, flush_interval_s=args.flush_interval,
                ready=lambda: print("recording", flush=True))
    except SoftsensorError as exc:
        print(f"softsensor: {exc}", file=sys.stderr)
        return 2
    print(f"recorded {n} messages", flush=True)
    return 0


__all__ = ["PLC_BUDGET", "BusRecorder", "main", "run", "stop_on_signals"]


if __name__ == "__main__":
    sys.exit(main())
