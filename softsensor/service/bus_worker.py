"""The estimator's worker: take input messages from a bus, step on one thread, send outputs.

:class:`BusWorker` hands every scan and lab message its input side delivers, in arrival order,
to an :class:`~softsensor.service.estimator_service.EstimatorService`, and sends what the
service returns through its output side (``estimate`` and ``health``); after every
``checkpoint_every`` ticks the service state is written through a
:class:`~softsensor.service.checkpoint.CheckpointStore`. The sides are the interfaces of
:mod:`softsensor.bus.transport`: on Zenoh (:func:`~softsensor.bus.zenoh_bus.zenoh_sides`: the
daemon, ``replay --via-zenoh``) or in memory (:mod:`softsensor.bus.memory`: ``replay``,
tests), so the daemon and the replay run the same worker.

On Zenoh the service runs on the worker's own thread: Zenoh's callback threads only enqueue (a
tick of the filter takes tens of milliseconds and must not hold them up), within the input
limits (:class:`InputLimits`). Behind a memory input the worker can run each message on the
thread that puts it (``thread=False``): the sender has nothing else to do, and nothing is
queued, handed between threads or waited for.

One path feeds the bus and the outputs: the worker's results, and what the daemon says from
its own thread (the watchdog's ``stalled`` health, the recorder's state) through
:meth:`BusWorker.publish_aside`, one message at a time with the worker's, so an operator's
screen never shows an older state after a newer one. (Not through the worker's queue: the
watchdog speaks when the worker is stuck.)
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from softsensor.bus.transport import BusMessage, InputSide, OutputSide
from softsensor.errors import SoftsensorError
from softsensor.log_throttle import Throttle, outside_text
from softsensor.service.checkpoint import CheckpointStore
from softsensor.service.estimator_service import EstimatorService, Output
from softsensor.service.logs import event
from softsensor.service.plc_scans import OTHER, PLC, REFUSED

log = logging.getLogger(__name__)


class _Call:
    """A function to run on the worker thread, with a completion event."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        self.fn = fn
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None


_STOP = object()


@dataclass(frozen=True)
class InputLimits:
    """What the estimator thread accepts from the bus (``[service]`` keys of the same names).

    ``rates_per_s`` maps an input kind to its sustained rate [messages per wall second];
    ``burst`` is how many may come at once above it (a PLC reconnecting, a lab catching up);
    ``max_queue`` and ``max_queue_bytes`` bound the messages waiting for the estimator thread
    and their payload bytes.
    """

    max_queue: int = 10**9
    max_queue_bytes: int | None = None
    rates_per_s: Mapping[str, float] = field(default_factory=dict)
    burst: float = 100.0
    max_bytes: int | None = None


class _Bucket:
    """A token bucket: ``rate`` tokens a second, at most ``burst`` saved up."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate, self.burst = float(rate), float(burst)
        self.tokens, self.at = float(burst), time.monotonic()

    def take(self, now: float) -> bool:
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


class BusWorker:
    """Runs an :class:`EstimatorService` between an input and an output side (module
    docstring).

    Parameters
    ----------
    service : EstimatorService
        The sans-I/O core (already restored from a checkpoint if resuming).
    inputs : InputSide
        Where the scan and lab messages come from; the worker opens it, with its limits.
    outputs : OutputSide
        Where the estimate and health messages go.
    checkpoints : CheckpointStore, optional
        Where to write the service state; None = never.
    checkpoint_every : int
        Ticks between checkpoints.
    on_output : callable, optional
        Called on the worker thread with every :class:`Output` after it was sent.
    limits : InputLimits, optional
        Queue bound, a rate per input kind and message size (drop and count beyond them);
        unbounded by default (a replay feeds a recorded day as fast as it can).
    decorate : callable, optional
        Called with every :class:`Output` before it is sent; what it returns is sent (the
        daemon adds what the service cannot know to health: the recorder's state).
    on_admitted : callable, optional
        Called (on the input side's thread) with every input message the limits admitted and
        its origin (``origin``'s answer): the daemon's recorder, so it records what the limits
        admitted and nothing they, or ``origin``, refused.
    origin : callable, optional
        ``origin(message)`` says who sent a message
        (:meth:`~softsensor.service.plc_scans.PlcScans.origin`): the PLC's own scans skip the
        rate limit and the queue bound (the poll period bounds them); another sender's scan
        while the PLC's arrive is dropped, neither estimated nor recorded (counted in
        ``dropped["other_sender"]``). None: every message from anyone (a replay).
    thread : bool
        Run the service on the worker's own thread (default). False: on the thread that
        delivers each message or calls the worker, nothing queued (a memory input, module
        docstring; never on Zenoh, whose threads must not wait for a tick).
    """

    def __init__(self, service: EstimatorService, inputs: InputSide, outputs: OutputSide, *,
                 checkpoints: CheckpointStore | None = None,
                 checkpoint_every: int = 1,
                 on_output: Callable[[Output], None] | None = None,
                 limits: InputLimits | None = None,
                 decorate: Callable[[Output], Output] | None = None,
                 on_admitted: Callable[[BusMessage, str], None] | None = None,
                 origin: Callable[[BusMessage], str] | None = None,
                 thread: bool = True) -> None:
        self.service = service
        self.on_admitted = on_admitted
        self.origin = origin
        self.decorate = decorate
        self.checkpoints = checkpoints
        self.checkpoint_every = max(1, int(checkpoint_every))
        self.on_output = on_output
        self.publisher = outputs  #: the output side
        self.n_in = 0  #: scan and lab messages processed
        self.n_out = 0  #: estimate and health messages sent
        self.n_errors = 0  #: messages whose processing raised
        self.last_tick_s: float | None = None  #: wall time of the last message that ticked
        self.last_tick_at: float = time.monotonic()  #: when the last estimate went out
        self.first_input_at: float | None = None  #: when the first input was queued
        self.limits = limits or InputLimits()
        self.dropped: dict[str, int] = {"queue_full": 0, "rate": 0, "too_large": 0,
                                        "shutdown": 0, "other_sender": 0}
        self._skip_inputs = False
        self._abandoned = False
        self._pending = 0  # input messages queued and not yet processed
        self._pending_bytes = 0  # and their payload bytes
        self._pending_lock = threading.Lock()  # the input's threads add, the worker removes
        self._buckets = {kind: _Bucket(rate, self.limits.burst)
                         for kind, rate in self.limits.rates_per_s.items()}
        self._drop_logged = 0.0
        self._throttle = Throttle()  # repeated failures: a line now and then, with a count
        self._ticks_unsaved = 0
        self._out_lock = threading.Lock()  # one message at a time to the bus and outputs
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        if thread:
            self._thread = threading.Thread(target=self._loop, name="estimator", daemon=True)
            self._thread.start()
        self.n_labs_received = 0  #: lab messages received (enqueued) so far
        self.subscription = inputs  #: the input side
        inputs.open(self._enqueue, max_bytes=self.limits.max_bytes,
                    on_too_large=lambda: self._drop("too_large"),
                    sized=self.limits.max_queue_bytes is not None)
        self._closed = False

    def _enqueue(self, message: BusMessage) -> None:
        """The input side's callback: queue the message for the worker thread (or run it,
        without one), or drop and count it when its source is over its rate or the queue is
        full (the thread must never starve)."""
        if message.kind == "lab":
            self.n_labs_received += 1
        if self.first_input_at is None:
            self.first_input_at = time.monotonic()
        origin = OTHER if self.origin is None else self.origin(message)
        plc = origin == PLC
        bucket = None if plc else self._buckets.get(message.kind)
        if bucket is not None and not bucket.take(time.monotonic()):
            self._drop("rate")
            return
        cap = self.limits.max_queue_bytes
        with self._pending_lock:
            full = not plc and (self._pending >= self.limits.max_queue or (
                cap is not None and self._pending_bytes + message.nbytes > cap))
            if not full and origin != REFUSED:
                self._pending += 1
                self._pending_bytes += message.nbytes
        if full:
            self._drop("queue_full")
            return
        if origin == REFUSED:  # not recorded either: a recorded day is what the estimator took
            self._drop("other_sender")
            return
        if self.on_admitted is not None:
            self.on_admitted(message, origin)  # before the worker can make an output of it
        self._hand(message)

    def _hand(self, item: Any) -> None:
        """Queue ``item`` for the worker's thread; without one, run it now."""
        if self._thread is None:
            self._run(item)
        else:
            self._q.put(item)

    def _drop(self, reason: str) -> None:
        self.dropped[reason] += 1
        now = time.monotonic()
        if now - self._drop_logged >= 10.0:  # one line per 10 s of a flood, not per message
            self._drop_logged = now
            event(log, "input_dropped", logging.WARNING, reason=reason, **self.dropped)

    @property
    def pending(self) -> int:
        """Input messages waiting for the estimator thread."""
        return self._pending

    # ------------------------------------------------------------------ worker thread
    def _loop(self) -> None:
        while True:
            item = self._q.get()
            if item is _STOP or self._abandoned:  # abandoned: the session is gone
                return
            self._run(item)

    def _run(self, item: _Call | BusMessage) -> None:
        """Run a call, or hand a message to the service and send its outputs."""
        if isinstance(item, _Call):
            try:
                item.result = item.fn()
            except BaseException as exc:  # noqa: BLE001 - handed to the caller
                item.error = exc
            item.done.set()
            return
        with self._pending_lock:
            self._pending -= 1
            self._pending_bytes -= item.nbytes
        if self._skip_inputs:
            self.dropped["shutdown"] += 1
            return
        try:
            t0 = time.perf_counter()
            outputs = self.service.on_message(item.kind, item.body, item.time_ns)
            if any(o.kind == "estimate" for o in outputs):
                self.last_tick_s = time.perf_counter() - t0
            self._publish(outputs)
        except Exception:  # noqa: BLE001 - one bad message must not stop the service
            self.n_errors += 1
            self._throttle.log(log, "processing", logging.ERROR,
                               "processing %s message failed", item.kind, exc_info=True)
        self.n_in += 1

    def _publish(self, outputs: list[Output]) -> None:
        with self._out_lock:
            for out in outputs:
                self._emit(out)
        if self._ticks_unsaved >= self.checkpoint_every:
            self._save()

    def _emit(self, out: Output) -> None:
        """Decorate, send and hand ``out`` to the hook (holding ``_out_lock``)."""
        if self.decorate is not None:
            out = self.decorate(out)
        self.publisher.put(out.kind, out.to_body(), out.time_ns)
        self.n_out += 1
        if out.kind == "estimate":
            self._ticks_unsaved += 1
            self.last_tick_at = time.monotonic()
        if self.on_output is not None:
            try:
                self.on_output(out)
            except Exception:  # noqa: BLE001 - a logging hook must not stop the service
                self._throttle.log(log, "hook", logging.ERROR, "output hook failed",
                                   exc_info=True)

    def _save(self) -> None:
        if self.checkpoints is None:
            self._ticks_unsaved = 0
            return
        try:
            self.checkpoints.save(self.service.checkpoint(),
                                  saved_at_ns=self.service.now_ns or time.time_ns(),
                                  unit=self.service.unit)
            self._ticks_unsaved = 0
        except SoftsensorError as exc:
            # tried again at the next tick, not at every message until then; and every tick
            # fails alike (a read-only folder): the news, not one line a tick
            self._ticks_unsaved = 0
            held = self._throttle.ready("checkpoint")
            if held is not None:
                event(log, "checkpoint_failed", logging.ERROR, error=outside_text(exc),
                      not_logged_since=held)

    # ------------------------------------------------------------------ public API
    def publish_aside(self, out: Output, timeout: float = 1.0) -> bool:
        """Send ``out`` from another thread than the worker (the daemon's watchdog and
        recorder news) through the worker's path (decorated, on the bus, to the hook), one
        message at a time with the worker's (module docstring). False, and nothing
        published, when the worker held the path for ``timeout`` seconds."""
        if not self._out_lock.acquire(timeout=timeout):
            self._throttle.log(log, "aside", logging.ERROR, "%s not published: the estimator "
                               "thread holds the outputs", out.kind)
            return False
        try:
            self._emit(out)
        finally:
            self._out_lock.release()
        return True

    def call(self, fn: Callable[[], Any], timeout: float = 60.0) -> Any:
        """Run ``fn`` on the worker thread after every message queued so far; its result."""
        c = _Call(fn)
        self._hand(c)
        if not c.done.wait(timeout):
            raise TimeoutError(f"estimator thread did not answer within {timeout:g} s")
        if c.error is not None:
            raise c.error
        return c.result

    def advance(self, now_ns: int) -> None:
        """Queue a passage of time to ``now_ns`` [ns] (closes windows of a silent PLC).

        Nobody waits on this call, so a failure is counted and logged here, as for a message.
        """
        def run() -> None:
            try:
                self._publish(self.service.advance(now_ns))
            except Exception:  # noqa: BLE001 - one bad tick must not stop the service
                self.n_errors += 1
                self._throttle.log(log, "advance", logging.ERROR,
                                   "advancing the estimator to %d failed", now_ns,
                                   exc_info=True)

        self._hand(_Call(run))

    def lab_file_refused(self, reason: str, time_ns: int) -> None:
        """Queue the news of a lab file refused by the daemon's folder (``reason``, at
        ``time_ns`` [ns]): counted by the service and told in health, in order with the
        messages. Nobody waits on this call (the folder's thread must not)."""
        def run() -> None:
            try:
                self._publish(self.service.lab_file_refused(reason, time_ns))
            except Exception:  # noqa: BLE001 - as for a message: counted, logged
                self.n_errors += 1
                self._throttle.log(log, "lab file", logging.ERROR,
                                   "telling a refused lab file failed", exc_info=True)

        self._hand(_Call(run))

    def sync(self, timeout: float = 60.0) -> None:
        """Wait until every message queued so far has been processed."""
        self.call(lambda: None, timeout)

    def flush(self, timeout: float = 60.0) -> None:
        """Tick every window left (end of a recorded day) and send the results."""
        self.call(lambda: self._publish(self.service.flush()), timeout)

    def save_checkpoint(self, timeout: float = 60.0) -> None:
        """Write the checkpoint now (after the queued messages)."""
        self.call(self._save, timeout)

    def close(self, *, checkpoint: bool = True, timeout: float = 60.0,
                drain: bool = True) -> None:
        """Stop receiving, process what is queued (``drain``; else skip the input messages
        still waiting, as a daemon stopping does: they are recorded already), write a last
        checkpoint, stop (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._skip_inputs = not drain
        self.subscription.close()
        stuck = False
        try:
            if checkpoint:
                self.save_checkpoint(timeout)
            else:
                self.sync(timeout)
        except TimeoutError:
            # a stuck thread is left behind (a daemon thread: it dies with the process) so
            # that stopping takes seconds; the last checkpoint written stays the one to resume
            stuck = self._abandoned = True
            event(log, "estimator_abandoned", logging.ERROR, waited_s=timeout,
                  pending=self.pending)
        finally:
            if self._thread is not None:
                self._q.put(_STOP)
                self._thread.join(0 if stuck else timeout)
            self.publisher.close()

    def __enter__(self) -> BusWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["BusWorker", "InputLimits"]
