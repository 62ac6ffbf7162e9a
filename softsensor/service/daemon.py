"""The estimator daemon: poller, lab input, estimator and recorder on one Zenoh peer.

``softsensor run --config config/dryer1.toml`` builds a :class:`Daemon` and awaits
:meth:`Daemon.run` until SIGTERM or SIGINT sets its stop event (the signal handlers do nothing
else). Inside one process, around one embedded Zenoh session (peer on ``127.0.0.1`` by
default, optionally connected to a router)::

    ModbusPoller --ScanPublisher--> plant/<unit>/scan ---+--> BusWorker (estimator thread)
    LabFolderWatcher --LabInput---> plant/<unit>/lab  ---+      | estimate, health
    (other publishers, e.g. a LIMS) plant/<unit>/lab  ---+      v
                                    softsensor/<unit>/{estimate,health}
    every key --> BusRecorder --> Recorder: <data_dir>/<unit>-YYYYMMDD.mcap (daily, UTC)

The estimator state is checkpointed after every tick (atomic replace, see
:mod:`.checkpoint`); a restart resumes from it, and the windows missed while the daemon was down
are ticked as stale gaps. A checkpoint whose times lie further ahead of the daemon's clock than
``max_future_s`` (written by a clock that was ahead) is refused like any other future time:
resumed, it would drop every real scan as late until the clock caught up. Logs are one line
per event (:mod:`.logs`).

Time: the daemon's clock (:mod:`.clock`) is the wall clock, a scaled clock for accelerated
demos, or the PLC's own clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from softsensor.bus.transport import INPUT_KINDS, OUTPUT_KINDS
from softsensor.bus.zenoh_bus import (
    Publisher,
    free_port,
    listening_endpoints,
    open_session,
    zenoh_sides,
)
from softsensor.errors import ConfigError, EstimationError, IngestError
from softsensor.estimate import Estimate, Health
from softsensor.estimation.interface import LabResult
from softsensor.ingest.historian_map import plant_lab_map
from softsensor.ingest.lab_input import LabFolderWatcher, LabInput, folder_rate
from softsensor.ingest.modbus_poller import ModbusPoller
from softsensor.ingest.tagmap import TagMap, load_tagmap
from softsensor.messages import lab_body
from softsensor.outputs.operator_output import OperatorOutput, abuse, lab_refused, operator_outputs
from softsensor.outputs.settings import output_settings
from softsensor.plantconfig import PlantConfig
from softsensor.presentation.display import (
    DisplaySettings,
    display_settings,
    local_clock,
    moisture_pct,
    moisture_pct_points,
)
from softsensor.recording.recorder import Recorder
from softsensor.service.advisor_tap import admitted_chain, advisor_tap
from softsensor.service.build import make_service
from softsensor.service.bus_recorder import BusRecorder
from softsensor.service.bus_worker import BusWorker, InputLimits
from softsensor.service.checkpoint import CheckpointStore, check_fits, checkpoint_time_ns
from softsensor.service.clock import ScaledClock, daemon_clock, read_plc_clock
from softsensor.service.descriptors import DescriptorWatch
from softsensor.service.estimator_service import EstimatorService, Output
from softsensor.service.estimators import default_kind
from softsensor.service.heap import TRIM_EVERY_S, trim
from softsensor.service.logs import event
from softsensor.service.plc_scans import HOLD_SCANS, PlcScans
from softsensor.service.scan_publisher import ScanPublisher
from softsensor.service.settings import PLC_CLOCK, ServiceSettings, bus_options, resolve_unit
from softsensor.service.time_gate import TimeGate
from softsensor.service.warmup import warm_up
from softsensor.service.watchdog import HealthQueryable, Watchdog

log = logging.getLogger(__name__)

#: Wall-clock period of the daemon's housekeeping (time passing, recorder, status) [s].
HOUSEKEEPING_S = 0.1
#: How often the open descriptors are counted [s, wall] (20,000 of them take about 5 ms).
DESCRIPTORS_EVERY_S = 2.0
#: Longest wait at shutdown for the estimator thread's last checkpoint [s]; a thread stuck
#: longer is left behind (it is a daemon thread) so SIGTERM is honoured within seconds.
SHUTDOWN_WAIT_S = 10.0


@dataclass
class DaemonInfo:
    """What a running daemon reports once it is up."""

    unit: str
    estimator: str
    endpoints: list[str]
    plc: str
    data_dir: str | None
    resumed: bool
    clock_start_ns: int
    outputs: tuple[str, ...] = ()  #: what the operator outputs serve (URLs)


def resolve_listen(endpoints: tuple[str, ...] | list[str]) -> list[str]:
    """``endpoints`` with port 0 (any free port) replaced by a free port chosen here: with
    Zenoh's admin space off the session cannot tell which port it took."""
    out = []
    for ep in endpoints:
        proto, _, addr = ep.partition("/")
        host, _, port = addr.rpartition(":")
        if proto in ("tcp", "udp") and port == "0" and host:
            ep = f"{proto}/{host}:{free_port(host.strip('[]'))}"
        out.append(ep)
    return out


def daemon_tagmap(settings: ServiceSettings, tagmap: TagMap | None = None) -> TagMap:
    """The tag map with the ``service`` PLC endpoint and a poll period scaled to plant time."""
    tm = tagmap if tagmap is not None else (
        load_tagmap(settings.tagmap) if settings.tagmap else load_tagmap())
    if settings.plc_host is not None or settings.plc_port is not None:
        tm = tm.with_endpoint(settings.plc_host or tm.modbus.host,
                              settings.plc_port or tm.modbus.port)
    if settings.time_scale != 1.0:
        tm = tm.with_settings(poll_period_s=tm.modbus.poll_period_s / settings.time_scale)
    return tm


def _pct(x: float | None, d: DisplaySettings) -> float | None:
    """Dry-basis moisture [kg/kg] as % on the display basis, to 0.01 (None stays None)."""
    return None if x is None else round(float(moisture_pct(x, d.moisture_basis)), 2)


def _pct_band(x: float | None, sd: float | None, d: DisplaySettings) -> float | None:
    """Two standard deviations of a dry-basis moisture as % points on the display basis."""
    if x is None or sd is None:
        return None
    return round(moisture_pct_points(2.0 * float(sd), float(x), d.moisture_basis), 2)


class Daemon:
    """Runs the whole service until a stop event (module docstring).

    Parameters
    ----------
    config : PlantConfig
        Plant config with calibrated parameters.
    settings : ServiceSettings
        The ``[service]`` table with command-line overrides applied.
    tagmap : TagMap, optional
        Use this tag map instead of ``settings.tagmap`` (tests).
    kind : str, optional
        The estimator (``--estimator``); default the config's ``estimator.kind``.
    resume : bool or str
        Continue from the checkpoint when there is one (True or ``"auto"``: an unusable one
        is moved aside and the daemon starts afresh; ``"required"``: it stops with a one-line
        error instead; False: ignore any checkpoint).
    """

    def __init__(self, config: PlantConfig, settings: ServiceSettings, *,
                 tagmap: TagMap | None = None, kind: str | None = None,
                 resume: bool = True) -> None:
        self.config = config
        self.settings = settings
        self.unit = resolve_unit(settings, config)
        self.kind = kind or default_kind(config)
        self.tagmap = daemon_tagmap(settings, tagmap)
        self.resume = resume
        self.store = CheckpointStore(settings.checkpoint)
        self.worker: BusWorker | None = None
        self.poller: ModbusPoller | None = None
        self.lab_input: LabInput | None = None
        self.recorder: Recorder | None = None
        self.bus_recorder: BusRecorder | None = None
        self.clock: ScaledClock | None = None
        self.info: DaemonInfo | None = None
        self.display = display_settings(config)
        self.output_settings = output_settings(config)
        self.lab_map = plant_lab_map(config)  # the lab folder's files: [lab], checked now
        self.advisor = advisor_tap(config)  # [advisor] enabled: the advice at every tick
        #: the operator outputs that run, by their table's name (``[outputs.<name>]``)
        self.outputs: dict[str, OperatorOutput] = {}
        #: the health last published (the watchdog's and the recorder's news build on it)
        self.latest_health: Health | None = None
        self.watchdog: Watchdog | None = None
        self.health: HealthQueryable | None = None
        self.resumed = False  #: the service continues from the checkpoint
        self._recording_said: str | None = None  #: recorder state health last said
        self.descriptors = DescriptorWatch()  #: open descriptors against the process limit
        self.plc_scans: PlcScans | None = None  #: the poller's scans known on the bus
        #: the PLC's clock [ns] and the monotonic time it was read (``clock_start = "plc"``)
        self._plc_clock: tuple[int, float] | None = None

    def _on_output(self, out: Output) -> None:
        """Log what went out and hand it to the health queryable and the operator outputs."""
        if isinstance(out, Estimate):
            # what an operator reads: % moisture on the [display] basis, local clock time
            d = self.display
            event(log, "tick", window_end=local_clock(out.time_ns, d), status=out.status,
                  moisture_out=_pct(out.moisture_out, d),
                  moisture_out_2sd=_pct_band(out.moisture_out, out.moisture_out_std, d),
                  moisture_in=_pct(out.moisture_in, d),
                  moisture_in_2sd=_pct_band(out.moisture_in, out.moisture_in_std, d),
                  unit=d.moisture_unit, lab_updated=out.lab_updated,
                  n_scans=None if out.window is None else out.window.n_scans,
                  window_end_ns=out.time_ns)
            for output in self.outputs.values():
                output.on_estimate(out)
            if self.advisor is not None and self.worker is not None:
                self.advisor.after(out, self.latest_health, self.worker.publisher.put,
                                   self.outputs.values())
            return
        event(log, "health", time_ns=out.time_ns, status=out.status, detail=out.detail)
        self.latest_health = out
        for output in self.outputs.values():
            output.on_health(out)

    async def run(self, stop: asyncio.Event,
                  ready: Callable[[DaemonInfo], None] | None = None) -> None:
        """Run until ``stop`` is set, then shut down cleanly (checkpoint, finished files)."""
        s = self.settings
        if s.clock_start == PLC_CLOCK:
            self._plc_clock = await read_plc_clock(self.tagmap, s.time_scale)
        doc = self._not_from_the_future(self._load_checkpoint())
        scan_period_s = self.tagmap.modbus.poll_period_s * s.time_scale
        # times far from the daemon's clock are refused (the clock starts below, before any
        # message can arrive: the gate reads it when one does)
        gate = TimeGate(self._now_ns, s.max_future_s, s.max_past_s)
        service = self._service(doc, scan_period_s, gate)
        # compile the estimator's kernels now, not in the first live tick (which would hold
        # the estimator thread, and every scan behind it, for tens of seconds on a cold cache)
        warm = await asyncio.to_thread(
            warm_up, lambda: make_service(self.config, s, self.kind, scan_period_s), self.config)
        event(log, "warmed_up", seconds=round(warm.seconds, 2),
              ticks=None if warm.stats is None else warm.stats.ticks, error=warm.error)
        saved = doc["saved_at_ns"] if self.resumed else None
        self.clock = clock = daemon_clock(s, self._plc_clock, saved)
        async with contextlib.AsyncExitStack() as stack:
            listen = resolve_listen(s.listen)
            session = open_session(mode=s.zenoh_mode, listen=listen,
                                   connect=list(s.connect), **bus_options(s, self.unit))
            stack.callback(session.close)
            stack.callback(self.descriptors.close)  # its reserve descriptor
            if s.record:
                self._record(stack, session, gate)
            self.worker = worker = self._worker(session, service)
            # stopping must not wait for a backlog: the queued inputs are recorded already
            stack.push_async_callback(asyncio.to_thread, functools.partial(
                worker.close, timeout=SHUTDOWN_WAIT_S, drain=False))
            self.health = HealthQueryable(session, self.unit, self._health_answer)
            stack.callback(self.health.close)
            publisher = Publisher(session, self.unit, clock=clock.now_ns)
            publisher.declare(INPUT_KINDS)
            stack.callback(publisher.close)
            # the outputs first: a port in use stops the daemon before it polls the PLC
            served = await self._start_outputs(stack)
            self._lab_input(stack, publisher, clock)
            poll_task = self._start_poller(stack, publisher, clock)
            m = self.tagmap.modbus
            endpoints = listening_endpoints(session) if s.zenoh_adminspace else listen
            self.info = DaemonInfo(self.unit, service.kind, endpoints,
                                   f"{m.host}:{m.port}", s.data_dir if s.record else None,
                                   self.resumed, clock.start_ns, served)
            event(log, "started", unit=self.unit, estimator=service.kind,
                  zenoh=",".join(self.info.endpoints) or "none", plc=self.info.plc,
                  data_dir=self.info.data_dir, time_scale=s.time_scale,
                  resumed=self.info.resumed, outputs=",".join(served) or "none",
                  clock_ns=clock.now_ns())  # plant time now: what a driver of the clock needs
            if ready is not None:
                ready(self.info)
            await self._housekeeping(stop, poll_task)
        event(log, "stopped", ticks=service.stats.ticks, stale_ticks=service.stats.stale_ticks,
              scans=service.stats.scans, checkpoints=self.store.n_saved)

    def _load_checkpoint(self) -> dict | None:
        """The checkpoint to resume from: None without one, with ``resume`` off, or when it
        fails its checks (then moved aside, see :meth:`_reject_checkpoint`)."""
        if not self.resume:
            return None
        try:
            return self.store.load()
        except ConfigError as exc:
            return self._reject_checkpoint(str(exc))

    def _not_from_the_future(self, doc: dict | None) -> dict | None:
        """``doc``, or None when its times are further ahead of the clock this daemon will
        run on than ``max_future_s`` (then rejected, :meth:`_reject_checkpoint`)."""
        if doc is None:
            return None
        latest = checkpoint_time_ns(doc)
        now = daemon_clock(self.settings, self._plc_clock, doc["saved_at_ns"]).now_ns()
        ahead_s = (latest - now) / 1e9
        if ahead_s <= self.settings.max_future_s:
            return doc
        self._reject_checkpoint(f"{self.store.path}: checkpoint from the future: its time is "
                                f"{ahead_s:.0f} s ahead of the daemon's clock (at most "
                                f"{self.settings.max_future_s:g} s)")
        return None

    def _reject_checkpoint(self, reason: str) -> None:
        """A checkpoint that cannot be used: with ``resume="required"`` a one-line error
        (exit 2); otherwise renamed ``*.bad-<ns>``, logged loudly, and a fresh start."""
        if self.resume == "required":
            raise ConfigError(f"{reason} (--resume=required: not starting afresh)")
        moved = self.store.move_aside()
        event(log, "checkpoint_rejected", logging.ERROR, reason=reason,
              moved_to=None if moved is None else str(moved), action="fresh start")

    def _now_ns(self) -> int:
        """The daemon's clock [ns] (started before the first message arrives)."""
        assert self.clock is not None
        return self.clock.now_ns()

    def _service(self, doc: dict | None, scan_period_s: float,
                 gate: TimeGate | None = None) -> EstimatorService:
        """A fresh estimator service, restored from the checkpoint ``doc`` when it fits
        (``gate``: refuses times far from the daemon's clock)."""
        service = make_service(self.config, self.settings, self.kind, scan_period_s,
                               time_gate=gate)
        if doc is None:
            return service
        # a checkpoint of another unit or estimator is a configuration question, not damage:
        # the operator decides (--no-resume), the file stays
        check_fits(doc, self.unit, service.kind, str(self.store.path), " (use --no-resume)")
        try:
            service.restore(doc["service"], where=str(self.store.path))
        except EstimationError as exc:
            self._reject_checkpoint(f"{self.store.path}: {exc}")
            return make_service(self.config, self.settings, self.kind, scan_period_s,
                                time_gate=gate)
        self.resumed = True
        event(log, "resumed", checkpoint=str(self.store.path),
              ticked_end_ns=service.ticked_end_ns, ticks=service.stats.ticks)
        return service

    def _record(self, stack: contextlib.AsyncExitStack, session: zenoh.Session,
                gate: TimeGate) -> None:
        """Record every key of the unit into the daily files, closed with ``stack``."""
        s = self.settings
        self.recorder = Recorder(s.data_dir, self.unit, chunk_size=s.chunk_size,
                                 flush_interval_s=s.flush_interval_s,
                                 reserve_bytes=s.record_reserve_bytes)
        self._recording_said = "ok"
        stack.callback(self.recorder.close)
        # the outputs from the bus; the inputs from the worker once its limits admit them
        self.bus_recorder = bus_rec = BusRecorder(
            session, self.recorder, unit=self.unit, kinds=OUTPUT_KINDS, gate=gate,
            max_topic_bytes_per_day=s.record_topic_bytes_per_day)
        stack.callback(bus_rec.close)

    def _lab_input(self, stack: contextlib.AsyncExitStack, publisher: Publisher,
                   clock: ScaledClock) -> None:
        """Publish lab results given to :attr:`lab_input` or dropped in the lab folder."""
        s = self.settings

        def _lab_sink(lab: LabResult) -> None:
            publisher.put("lab", lab_body(lab), lab.log_time_ns)
            for output in self.outputs.values():
                output.on_lab(lab)
            d = self.display  # as a tick line: the plant's clock, % on the display basis
            event(log, "lab", sample_id=lab.sample_id,
                  sample_time=local_clock(lab.sample_time_ns, d),
                  moisture_out=_pct(lab.moisture_out, d), unit=d.moisture_unit,
                  sample_time_ns=lab.sample_time_ns, log_time_ns=lab.log_time_ns)

        self.lab_input = LabInput(_lab_sink, clock=clock.now_ns)
        assert self.worker is not None
        # a result the estimator refuses frees its id (a corrected one is then taken)
        self.worker.service.on_lab_refused = lab_refused(self.lab_input.forget, self.outputs)
        if s.lab_dir is not None:
            watcher = LabFolderWatcher(s.lab_dir, self.lab_input,
                                       poll_s=max(s.lab_poll_s / s.time_scale, 0.05),
                                       settle_s=s.lab_settle_s,
                                       zone=self.display.zone,
                                       lab_map=self.lab_map,
                                       rate_per_s=folder_rate(
                                           s.max_lab_rate_per_h, self._window_s(),
                                           s.time_scale),
                                       on_reject=self._lab_file_rejected).start()
            self.worker.service.on_lab_refused = lab_refused(watcher.forget, self.outputs)
            stack.callback(watcher.close)

    def _lab_file_rejected(self, reason: str) -> None:
        """A file the lab folder rejected: counted and told in health like a refused result
        (the estimator thread's counters, in order with the bus messages)."""
        if self.worker is not None and self.clock is not None:
            self.worker.lab_file_refused(reason, self.clock.now_ns())

    def _window_s(self) -> float:
        """The estimator's window [s, plant time]."""
        assert self.worker is not None
        return float(self.worker.service.window.period_s)

    async def _start_outputs(self, stack: contextlib.AsyncExitStack) -> tuple[str, ...]:
        """Start the enabled operator outputs, stopped with ``stack``; what they serve."""
        served, outputs = [], {}
        for output in operator_outputs(
                self.output_settings, self.display, self.unit,
                clock=self.clock.now_ns if self.clock else time.time_ns,
                time_scale=self.settings.time_scale, counters=self._counters(),
                tick_seconds=lambda: None if self.worker is None
                else self.worker.last_tick_s):
            served.append(await output.start())
            stack.push_async_callback(output.stop)
            outputs[output.name] = output
        # handed over whole: the estimator thread may already loop over them (a peer's scans
        # arrive while OPC UA takes its second to start)
        self.outputs = outputs
        return tuple(served)

    def _counters(self) -> dict[str, tuple[str, Callable[[], float]]]:
        """The daemon's counters for Prometheus, read from its parts at scrape time."""
        def stats():
            assert self.worker is not None
            return self.worker.service.stats

        def poll():
            assert self.poller is not None
            return self.poller.stats

        return {
            "softsensor_ticks": ("estimator ticks", lambda: stats().ticks),
            "softsensor_stale_ticks": ("ticks of windows without enough scans",
                                       lambda: stats().stale_ticks),
            "softsensor_scans": ("scans received", lambda: stats().scans),
            "softsensor_labs_accepted": ("lab results accepted", lambda: stats().labs_accepted),
            "softsensor_labs_refused": ("lab results and lab files refused",
                                        lambda: stats().labs_refused),
            "softsensor_lab_files_refused": ("lab files refused whole by the lab folder",
                                             lambda: stats().lab_files_refused),
            "softsensor_poller_reads": ("PLC polls", lambda: poll().scans),
            "softsensor_poller_read_failures": ("PLC reads that failed",
                                                lambda: poll().read_failures),
        }

    def _start_poller(self, stack: contextlib.AsyncExitStack, publisher: Publisher,
                      clock: ScaledClock) -> asyncio.Task[None]:
        """Start polling the PLC; ``stack`` stops the poller (10 s at most) on the way out."""
        assert self.plc_scans is not None
        self.poller = poller = ModbusPoller(self.tagmap,
                                            ScanPublisher(publisher, self.plc_scans.sent),
                                            clock_ns=clock.now_ns, monotonic=clock.monotonic)
        poll_stop = asyncio.Event()
        poll_task = asyncio.create_task(poller.run(poll_stop), name="modbus-poller")

        async def _stop_poller() -> None:
            poll_stop.set()
            try:
                await asyncio.wait_for(poll_task, 10.0)
            except TimeoutError:
                log.error("poller did not stop within 10 s")

        stack.push_async_callback(_stop_poller)
        return poll_task

    def _worker(self, session: zenoh.Session, service: EstimatorService) -> BusWorker:
        """The estimator's worker on the Zenoh session, with the input limits of ``[service]``
        (rates in plant time, so per wall second they scale with ``time_scale``) and its
        watchdog."""
        s = self.settings
        # the PLC's scans told apart from other senders' (the clock starts before the worker)
        assert self.clock is not None
        self.plc_scans = PlcScans(self.clock.now_ns,
                                  self.tagmap.modbus.poll_period_s * s.time_scale,
                                  hold_scans=HOLD_SCANS if s.plc_scans_first else 0)
        limits = InputLimits(
            max_queue=s.max_queue, max_queue_bytes=s.max_queue_bytes,
            max_bytes=s.max_message_bytes,
            rates_per_s={"scan": s.max_scan_rate_hz * s.time_scale,
                         "lab": s.max_lab_rate_per_h / 3600.0 * s.time_scale})
        worker = BusWorker(service, *zenoh_sides(session, self.unit),
                             checkpoints=self.store, checkpoint_every=s.checkpoint_every,
                             on_output=self._on_output, limits=limits,
                             decorate=self._decorate,
                             on_admitted=admitted_chain(self.advisor, self.bus_recorder),
                             origin=self.plc_scans.origin)
        window_wall = service.window.period_s / s.time_scale
        grace = (s.gap_after_s + s.tick_delay_s) / s.time_scale
        self.watchdog = Watchdog(window_wall, grace, lambda: worker.last_tick_at,
                                 lambda: worker.pending, lambda: worker.first_input_at)
        return worker

    def _recording(self) -> str | None:
        """The recorder's state for health: ``ok``, why it is paused, or None (not recording)."""
        r, b = self.recorder, self.bus_recorder
        if r is None:
            return None
        if r.failure:
            return r.failure
        if b is not None and b.capped:  # names only: a count would change it every message
            return (f"the day's cap (service.record_topic_bytes_per_day) reached for "
                    f"{', '.join(sorted(b.capped))}")
        return "ok"

    def _decorate(self, out: Output) -> Output:
        """Health says when recording is paused (estimates go on without it), what the
        input limits dropped, and, in ``resources``, when the open file descriptors near the
        process limit (:class:`~softsensor.service.descriptors.DescriptorWatch`)."""
        if not isinstance(out, Health):
            return out
        capped = None if self.bus_recorder is None or not self.bus_recorder.capped \
            else dict(self.bus_recorder.capped)
        return out.at(out.time_ns, recording=self._recording(),
                      resources=self.descriptors.said, inputs_dropped=None if self.worker is None
                      else dict(self.worker.dropped), recording_capped=capped)

    def _recording_changed(self) -> None:
        """Publish health at once when recording pauses or resumes (not only at the next
        tick): the one health line an operator sees for a full disk."""
        state = self._recording()
        if state == self._recording_said or self.latest_health is None \
                or self.worker is None or self.clock is None:
            return
        self._recording_said = state
        event(log, "recording", logging.ERROR if state != "ok" else logging.INFO,
              state=state, lost=None if self.recorder is None else self.recorder.n_lost)
        self.worker.publish_aside(self.latest_health.at(self.clock.now_ns()))

    def _health_answer(self) -> dict[str, Any]:
        """A health query's answer: the last health body, with the watchdog's verdict, the
        inputs' counters and the outputs' abuse counters now."""
        latest = self.latest_health
        doc = ({"status": "stale", "detail": "no estimate yet", "unit": self.unit}
               if latest is None else latest.to_body())
        p, w = self.worker, self.watchdog
        return {**doc, "stalled": bool(w is not None and w.stalled), "recording": self._recording(),
                "last_tick_age_s": None if p is None
                else round(time.monotonic() - p.last_tick_at, 1),
                "pending": None if p is None else p.pending,
                "dropped": None if p is None else dict(p.dropped), "abuse": abuse(self.outputs)}

    def _watch(self) -> None:
        """Publish ``stalled`` health when the estimator thread is late (:class:`Watchdog`),
        through the worker's one path to the bus and the outputs."""
        assert self.worker is not None and self.clock is not None
        if self.watchdog is None:
            return
        stall = self.watchdog.check()
        if stall is None:
            return
        now = self.clock.now_ns()
        base = self.latest_health or Health.initial(now, self.unit, self.worker.service.kind)
        self.worker.publish_aside(base.at(now, stall=stall))

    def _descriptors_changed(self) -> None:
        """Count the open descriptors; publish health at once when they near the process
        limit or are clear of it again."""
        said = self.descriptors.said
        now_said = self.descriptors.check()
        if (said is None) == (now_said is None) or self.latest_health is None \
                or self.worker is None or self.clock is None:
            return
        event(log, "descriptors", logging.ERROR if now_said else logging.INFO,
              state=now_said or "ok")
        self.worker.publish_aside(self.latest_health.at(self.clock.now_ns()))

    async def _housekeeping(self, stop: asyncio.Event, poll_task: asyncio.Task[None]) -> None:
        assert self.worker is not None and self.clock is not None
        next_status = time.monotonic() + self.settings.status_every_s
        next_descriptors = time.monotonic()
        next_trim = time.monotonic() + TRIM_EVERY_S
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), HOUSEKEEPING_S)
            if poll_task.done():
                exc = poll_task.exception()
                raise IngestError(f"the Modbus poller stopped: {exc!r}")
            self.worker.advance(self.clock.now_ns())
            self._watch()
            self._recording_changed()
            if time.monotonic() >= next_descriptors:
                next_descriptors = time.monotonic() + DESCRIPTORS_EVERY_S
                self._descriptors_changed()
            if time.monotonic() >= next_status:
                next_status += self.settings.status_every_s
                self._status()
            if time.monotonic() >= next_trim:  # what a flood took, back to the system
                next_trim = time.monotonic() + TRIM_EVERY_S
                trim()

    def _status(self) -> None:
        assert self.worker is not None and self.poller is not None
        st = self.worker.service.stats
        p = self.poller.stats
        event(log, "status", plc_connected=self.poller.connected, polls=p.scans,
              read_failures=p.read_failures, scans=st.scans, ticks=st.ticks,
              stale_ticks=st.stale_ticks, labs_accepted=st.labs_accepted,
              labs_refused=st.labs_refused, lab_files_refused=st.lab_files_refused,
              last_lab_refusal=self.worker.service.last_lab_refusal,
              checkpoints=self.store.n_saved,
              recorded=None if self.recorder is None else self.recorder.n_written,
              recording=self._recording())


__all__ = ["Daemon", "DaemonInfo", "daemon_tagmap"]
