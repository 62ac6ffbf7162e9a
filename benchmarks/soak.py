"""Soak: the daemon for days at 600x real time with faults injected (issue 14).

``softsensor run`` runs as a subprocess against a simulated PLC (a
:class:`~softsensor.plant.plc_server.PlcServer` serving a virtual-plant record from this
process, its lab results dropped into the daemon's lab folder when due). Every
``--fault-every`` plant hours one fault from the list below is injected, in turn:

* ``plc_restart``: the PLC goes away for 20 plant minutes and comes back on the same port;
* ``plc_stall``: the PLC's port accepts and never answers for 30 plant minutes;
* ``future_scan``: one scan stamped two days ahead, from another bus peer;
* ``negative_scan``: one scan stamped ``time_ns = -5``;
* ``bad_json``: a scan payload that is not JSON, and one that is a JSON list;
* ``lab_flood``: 5,000 lab messages from another bus peer as fast as it can send;
* ``corrupt_checkpoint``: SIGTERM, bytes of the checkpoint flipped, start again;
* ``sigkill``: SIGKILL, start again (from the checkpoint);
* ``huge_values`` (issue 25, item 1): two scans of ``T_air_in = 1e308`` in one window, from
  another bus peer;
* ``implausible_input`` (item 3): the PLC serves ``T_air_in`` at 690 K (inside the tag map's
  range) for 20 scans, then a 120 K spike for 20 scans;
* ``future_checkpoint`` (item 4): SIGTERM, the checkpoint's times moved 31 days ahead (a
  clock that was ahead; checksum made to match), start again;
* ``disk_full`` (item 5): the recording folder (a 256 MB tmpfs when this process may mount
  one, else the fault is skipped and says so) filled to the last byte for 30 plant minutes,
  across whatever day change falls in it, then freed.

The daemon serves all four operator outputs (Modbus, Prometheus, OPC UA, web page) on free
loopback ports. Measured and printed as one JSON document: every 600 s window after the first
hour must have a non-stale estimate recorded, except within ``--heal-windows`` windows after a
fault that interrupts data (PLC faults, restarts); the daemon's resident memory per plant day
(flat: the last day's peak at most 1.25 times the first's, over the runs that lived through
both; and its peak against 300 MB); the number of tracebacks in the daemon's stderr (zero);
every recorded day file readable (``--allow-truncated`` only for a file a SIGKILL or the full
disk cut) and none empty; no ``ok`` estimate of nonsense (outlet moisture outside 0.02 to 0.25
kg/kg on a plant whose truth stays near 0.10). Exit status 0 when all hold.

    python benchmarks/soak.py [--days 7] [--speed 600] [--fault-every 6] [--seed 3]

``--days 0.5`` checks the harness in about a minute; the issue's run is ``--days 7`` (about
17 minutes of wall time at 600x).

Memory under a flood (issue 31 item 2), ``--flood N``: after the soak's days (``--days 0`` for
the flood alone), the daemon's resident memory at rest (the median of ``--settle`` seconds of
samples, after ``--settle`` seconds without faults) is the baseline; then ``N`` times a bus peer
publishes 60 kB scans (under ``max_message_bytes``) as fast as it can for 10 s, and the resident
memory at rest after each is compared with the baseline. Targets in ``benchmarks/targets.json``
(``soak_memory``): baseline at most 250 MB, after every flood at most 1.1 times the baseline.
``--flood-json FILE`` writes this phase's numbers with the targets (the committed run:
``benchmarks/results/soak_flood.json``)::

    python benchmarks/soak.py --days 0 --speed 60 --flood 2 --flood-json FILE.json
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from softsensor.bus.zenoh_bus import Publisher, open_session, wait_for_peers
from softsensor.ingest.tagmap import load_tagmap
from softsensor.plant.plc_feed import PlantFeed
from softsensor.plant.plc_server import PlcServer
from softsensor.plant.simulator import simulate_day
from softsensor.plantconfig import default_config_path, load_plant_config
from softsensor.recording.mcap_day import read_day
from softsensor.service.checkpoint import state_digest
from softsensor.signals import TOPIC_ESTIMATE

WINDOW_NS = 600 * 10**9
FAULTS = ("plc_restart", "plc_stall", "future_scan", "negative_scan", "bad_json",
          "lab_flood", "corrupt_checkpoint", "sigkill", "huge_values", "implausible_input",
          "future_checkpoint", "disk_full")
#: Faults that interrupt the data (windows right after them may be stale).
INTERRUPTING = {"plc_restart", "plc_stall", "corrupt_checkpoint", "sigkill",
                "future_checkpoint",
                # its window loses 40 of 60 T_air_in values: stale by design, the model holds
                "implausible_input"}
#: Faults after which a day file may lack its footer (read with --allow-truncated).
CUTTING = {"sigkill", "disk_full"}
#: An ok estimate outside this is nonsense on the soak's plant (truth near 0.10) [kg/kg].
SANE_MOISTURE_OUT = (0.02, 0.25)
#: Size of the recording folder's file system when one can be mounted.
DISK = "256m"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Plc:
    """The simulated PLC on its own event-loop thread; stoppable, restartable, stallable."""

    def __init__(self, feed: PlantFeed, port: int, period_s: float) -> None:
        self.feed, self.port, self.period_s = feed, port, period_s
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.server: PlcServer | None = None
        self.override: list[tuple[str, float | None, int]] = []  # (signal, value, scans)

    def values(self) -> dict[str, float]:
        """The feed's next scan, with a broken sensor's value while one is queued."""
        v = self.feed.next_values()
        if self.override:
            name, value, n = self.override[0]
            if value is not None:  # (None: the sensor is sane for these scans)
                v = {**v, name: value}
            self.override[0] = (name, value, n - 1)
            if n <= 1:
                self.override.pop(0)
        return v

    def _run(self, coro, timeout: float = 20.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def start(self) -> None:
        self.server = PlcServer(load_tagmap(), self.values, port=self.port,
                                period_s=self.period_s)
        self._run(self.server.start())

    def stop(self) -> None:
        if self.server is not None:
            self._run(self.server.stop())
            self.server = None

    def stall(self, wall_s: float, before_restart) -> None:
        """Listen on the PLC's port, accept, never answer, for ``wall_s`` seconds; then call
        ``before_restart()`` and serve again."""
        self.stop()
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", self.port))
            s.listen(8)
            s.settimeout(0.1)
            held, end = [], time.monotonic() + wall_s
            while time.monotonic() < end:
                try:
                    held.append(s.accept()[0])
                except TimeoutError:
                    pass
            for c in held:
                c.close()
        before_restart()
        self.start()

    def close(self) -> None:
        self.stop()
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


class DaemonProcess:
    """``softsensor run`` as a subprocess; stderr kept, RSS sampled."""

    def __init__(self, config: Path, plc_port: int, workdir: Path) -> None:
        self.config, self.plc_port, self.workdir = config, plc_port, workdir
        self.proc: subprocess.Popen | None = None
        self.runs = 0
        self.stderr_paths: list[Path] = []
        self.rss: list[tuple[int, float]] = []  # (run, MB)

    def start(self, clock_start_ns: int) -> None:
        err = self.workdir / f"daemon-{self.runs}.stderr"
        self.stderr_paths.append(err)
        cmd = [sys.executable, "-m", "softsensor.cli", "run", "--config", str(self.config),
               "--plc", f"127.0.0.1:{self.plc_port}", "--clock-start", str(clock_start_ns)]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err.open("w"),
                                     cwd=self.workdir, env=dict(os.environ, PYTHONUNBUFFERED="1"))
        self.runs += 1

    def sample_rss(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        try:
            for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    self.rss.append((self.runs - 1, int(line.split()[1]) / 1024))
        except FileNotFoundError:
            pass

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> float:
        """Send ``sig``; seconds until the process exited."""
        assert self.proc is not None
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        return time.monotonic() - t0

    def tracebacks(self) -> int:
        return sum(p.read_text(errors="replace").count("Traceback") for p in self.stderr_paths)


def write_config(workdir: Path, listen_port: int, speed: float) -> Path:
    cfg = workdir / "plant.toml"
    cfg.write_text(default_config_path().read_text() + f"""
[service]
data_dir = "{workdir / 'rec'}"
checkpoint = "{workdir / 'state' / 'checkpoint.json'}"
lab_dir = "{workdir / 'lab'}"
zenoh_listen = ["tcp/127.0.0.1:{listen_port}"]
time_scale = {speed}
chunk_size = 16384
flush_interval_s = 1.0
status_every_s = 10.0
log_format = "json"

[outputs.modbus]
enabled = true
port = 0

[outputs.prometheus]
enabled = true
port = 0

[outputs.opcua]
enabled = true
port = {free_port()}

[outputs.web]
enabled = true
port = 0
""")
    return cfg


def bus_fault(kind: str, endpoint: str, now_ns: int) -> None:
    """Publish the bus faults from a separate peer."""
    with open_session(port=None, connect=[endpoint]) as s:
        if not wait_for_peers(s, timeout=10.0):
            raise RuntimeError("the fault peer did not reach the daemon")
        pub = Publisher(s, "dryer1")
        pub.declare(("scan", "lab"))
        time.sleep(0.3)  # declarations propagate
        scan = {"T_air_in": 480.0, "m_air": 82.0}
        if kind == "future_scan":
            pub.put("scan", scan, now_ns + 2 * 86_400 * 10**9)
        elif kind == "negative_scan":
            pub.put("scan", scan, -5)
        elif kind == "bad_json":
            s.put("plant/dryer1/scan", b"{not json")
            s.put("plant/dryer1/scan", b"[1, 2, 3]")
        elif kind == "lab_flood":
            for i in range(5000):
                pub.put("lab", {"sample_time_ns": now_ns - 3600 * 10**9, "moisture_out": 0.1,
                                "sample_id": f"flood-{now_ns}-{i}"}, now_ns)
        elif kind == "huge_values":
            pub.put("scan", {"T_air_in": 1e308}, now_ns)
            pub.put("scan", {"T_air_in": 1e308}, now_ns + 10**9)
        time.sleep(0.5)
        pub.close()


def from_the_future(path: Path, days: float = 31.0) -> None:
    """Move a checkpoint's times ``days`` ahead, checksum made to match: what a daemon whose
    clock was ahead would have written."""
    doc = json.loads(path.read_text())
    shift = int(days * 86_400 * 10**9)
    doc["saved_at_ns"] += shift
    state = doc["service"]
    for key in ("now_ns", "ticked_end_ns", "closed_end_ns", "last_scan_ns"):
        if isinstance(state.get(key), int):
            state[key] += shift
    state["window_scans"] = [[t + shift, b] for t, b in state["window_scans"]]
    doc["sha256"] = state_digest(state)
    path.write_text(json.dumps(doc))


@contextlib.contextmanager
def small_disk(folder: Path):
    """Mount a tmpfs of :data:`DISK` on ``folder``; yields whether it is mounted."""
    folder.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK}", "tmpfs", str(folder)],
                          capture_output=True, text=True, check=False)
    try:
        yield done.returncode == 0
    finally:
        if done.returncode == 0:
            subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path) -> Path:
    """Take every free byte of ``folder``'s (small, mounted) file system."""
    st = os.statvfs(folder)
    assert st.f_blocks * st.f_frsize <= 512 * 1024**2, f"{folder} is not the soak's small disk"
    filler = folder / "filler.bin"
    block = b"\0" * (1 << 20)
    with open(filler, "wb", buffering=0) as f, contextlib.suppress(OSError):
        while True:
            f.write(block)
    return filler


def corrupt(path: Path) -> None:
    data = bytearray(path.read_bytes())
    for i in range(0, len(data), max(1, len(data) // 7)):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))


class Clock:
    """The daemon's plant clock as this process sees it: per daemon run, its plant time when
    it logged ``started`` (``clock_ns``) and the wall time of that line. (The daemon's clock
    runs from before that line: warm-up, outputs and bus take a second or two, minutes of
    plant time at 600x; taking the line's own reading keeps the windows excused for a fault
    where the daemon had them.)"""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.runs: list[tuple[float, int]] = []

    def started(self, ready: tuple[float, int]) -> None:
        """``ready``: the wall time [s since the epoch] and plant time [ns] of the line."""
        wall, plant = ready
        self.runs.append((time.monotonic() - (time.time() - wall), plant))

    def now_ns(self) -> int:
        wall0, start = self.runs[-1]
        return start + int((time.monotonic() - wall0) * self.speed * 1e9)


def wait_ready(d: DaemonProcess, timeout: float = 120.0) -> tuple[float, int]:
    """Wait until the daemon's log (stderr, JSON lines) says ``started``; the line's wall time
    [s since the epoch] and the daemon's plant time then [ns]."""
    from datetime import datetime

    end = time.monotonic() + timeout
    err = d.stderr_paths[-1]
    while time.monotonic() < end:
        for line in err.read_text(errors="replace").splitlines():
            doc = json.loads(line) if line.startswith("{") else {}
            if doc.get("event") == "started":
                wall = datetime.fromisoformat(doc["ts"].replace("Z", "+00:00")).timestamp()
                return wall, int(doc["clock_ns"])
        if d.proc is not None and d.proc.poll() is not None:
            raise RuntimeError(f"daemon exited: {err.read_text()[-2000:]}")
        time.sleep(0.05)
    raise RuntimeError("daemon did not start in time")


def catch_up(feed: PlantFeed, t_ns: int) -> None:
    """Skip the feed's scans up to ``t_ns`` (the PLC was away while plant time went on; its
    lab results due meanwhile are dropped into the folder at once, as after an outage)."""
    while feed.plant_time_ns < t_ns and not feed.finished:
        feed.next_values()


def restart(d: DaemonProcess, plc: Plc, feed: PlantFeed, clock: Clock, kind: str,
            checkpoint: Path) -> dict:
    """Stop the PLC and the daemon (SIGTERM or SIGKILL), maybe corrupt the checkpoint, start
    the daemon where its clock was (plant time goes on), then the PLC, caught up."""
    plc.stop()
    took = d.stop(signal.SIGKILL if kind == "sigkill" else signal.SIGTERM)
    code = d.proc.returncode if d.proc is not None else None
    if kind == "corrupt_checkpoint" and checkpoint.is_file():
        corrupt(checkpoint)
    if kind == "future_checkpoint" and checkpoint.is_file():
        from_the_future(checkpoint)
    t = clock.now_ns()
    d.start(t)
    clock.started(wait_ready(d))
    catch_up(feed, clock.now_ns())
    plc.start()
    return {"stop_s": round(took, 2), "exit_code": code}


def inject(kind: str, d: DaemonProcess, plc: Plc, feed: PlantFeed, clock: Clock,
           endpoint: str, workdir: Path, speed: float, disk: bool) -> dict:
    if kind == "plc_restart":
        plc.stop()
        time.sleep(1200 / speed)
        catch_up(feed, clock.now_ns())
        plc.start()
        return {}
    if kind == "plc_stall":
        plc.stall(1800 / speed, lambda: catch_up(feed, clock.now_ns()))
        return {}
    if kind in ("future_scan", "negative_scan", "bad_json", "lab_flood", "huge_values"):
        bus_fault(kind, endpoint, clock.now_ns())
        return {}
    if kind == "implausible_input":
        plc.override += [("T_air_in", 690.0, 20), ("T_air_in", None, 20),
                         ("T_air_in", 600.0, 20)]
        return {}
    if kind == "disk_full":
        if not disk:
            return {"skipped": "no small file system could be mounted (needs root)"}
        filler = fill(workdir / "rec")
        time.sleep(1800 / speed)
        filler.unlink()
        return {}
    return restart(d, plc, feed, clock, kind, workdir / "state" / "checkpoint.json")


def recorded(workdir: Path) -> tuple[list[int], list[str], list[str], list[dict]]:
    """Window ends of the non-stale estimates in every recorded file, the files that need
    ``--allow-truncated`` (or cannot be read at all), the empty files, and the ``ok``
    estimates of nonsense."""
    ends: list[int] = []
    problems: list[str] = []
    empty: list[str] = []
    nonsense: list[dict] = []
    lo, hi = SANE_MOISTURE_OUT
    for f in sorted((workdir / "rec").glob("*.mcap")):
        if f.stat().st_size == 0:
            empty.append(f.name)
            continue
        try:
            day = read_day(f, topics=[TOPIC_ESTIMATE])
        except Exception as exc:  # noqa: BLE001 - reported, then read the intact part
            problems.append(f"{f.name}: {exc}")
            day = read_day(f, topics=[TOPIC_ESTIMATE], allow_truncated=True)
        for _t, body in day.topic(TOPIC_ESTIMATE):
            mo = body.get("moisture_out")
            if body.get("status") != "stale" and mo is not None:
                ends.append(int(body["window_end_ns"]))
            if body.get("status") == "ok" and (mo is None or not lo <= mo <= hi):
                nonsense.append({"window_end_ns": body.get("window_end_ns"),
                                 "moisture_out": mo})
    return sorted(set(ends)), problems, empty, nonsense


def missing_windows(ends: list[int], t0: int, t1: int, excused: list[tuple[int, int]]
                    ) -> list[int]:
    """Window ends in ``(t0, t1]`` without an estimate and outside every excused interval."""
    have = set(ends)
    first = (t0 // WINDOW_NS + 1) * WINDOW_NS
    out = []
    for end in range(first, t1 - WINDOW_NS, WINDOW_NS):
        if end not in have and not any(a <= end <= b for a, b in excused):
            out.append(end)
    return out


#: A flood scan's padding: 60 kB, under the daemon's ``max_message_bytes`` (64 kB).
FLOOD_PAD = "x" * 60_000
TARGETS = Path(__file__).with_name("targets.json")


def flood_bus(endpoint: str, now_ns: int, seconds: float) -> int:
    """Publish 60 kB scans from another peer as fast as it can for ``seconds``; how many."""
    with open_session(port=None, connect=[endpoint]) as s:
        if not wait_for_peers(s, timeout=10.0):
            raise RuntimeError("the flood peer did not reach the daemon")
        pub = Publisher(s, "dryer1")
        pub.declare(("scan",))
        time.sleep(0.3)  # declarations propagate
        n, end = 0, time.monotonic() + seconds
        while time.monotonic() < end:
            pub.put("scan", {"T_air_in": 480.0, "m_air": 82.0, "pad": FLOOD_PAD}, now_ns + n)
            n += 1
        time.sleep(0.5)
        pub.close()
    return n


def resting_rss(d: DaemonProcess, seconds: float) -> tuple[float, float]:
    """Wait ``seconds`` (the daemon settles), then sample its RSS once a second for
    ``seconds``: the median and the peak of the samples [MB]."""
    time.sleep(seconds)
    n0 = len(d.rss)
    for _ in range(max(1, int(seconds))):
        d.sample_rss()
        time.sleep(1.0)
    got = [v for _r, v in d.rss[n0:]] or [float("nan")]
    return statistics.median(got), max(got)


def flood_phase(d: DaemonProcess, clock: Clock, endpoint: str, floods: int, settle_s: float,
                flood_s: float = 10.0) -> dict:
    """The daemon's resident memory at rest, then after each of ``floods`` floods (module
    docstring)."""
    base, base_peak = resting_rss(d, settle_s)
    runs = []
    for _ in range(floods):
        n0 = len(d.rss)
        sent: list[int] = []
        t = threading.Thread(target=lambda out=sent: out.append(
            flood_bus(endpoint, clock.now_ns(), flood_s)))
        t.start()
        while t.is_alive():
            d.sample_rss()
            time.sleep(0.5)
        peak = max([v for _r, v in d.rss[n0:]] or [float("nan")])
        after, _ = resting_rss(d, settle_s)
        runs.append({"scans_sent": sum(sent), "mb_sent": round(sum(sent) * 60e3 / 1e6, 1),
                     "rss_peak_mb": round(peak, 1), "rss_after_mb": round(after, 1),
                     "after_over_baseline": round(after / base, 3)})
    return {"rss_baseline_mb": round(base, 1), "rss_baseline_peak_mb": round(base_peak, 1),
            "flood_s": flood_s, "settle_s": settle_s, "floods": runs}


def memory_by_day(rss: list[tuple[int, float]], samples_per_day: int) -> list[float]:
    """Peak RSS [MB] per plant day of samples (one sample per wall second)."""
    return [round(max(v for _r, v in rss[i:i + samples_per_day]), 1)
            for i in range(0, len(rss), samples_per_day)]


def soak(args: argparse.Namespace) -> dict:
    workdir = Path(args.workdir or tempfile.mkdtemp(prefix="softsensor-soak-"))
    with small_disk(workdir / "rec") as disk:
        return _soak(args, workdir, disk)


def _soak(args: argparse.Namespace, workdir: Path, disk: bool) -> dict:
    cfg = load_plant_config()
    day = simulate_day(cfg, args.days * 24 + 1, seed=args.seed)
    (workdir / "lab").mkdir(parents=True, exist_ok=True)
    feed = PlantFeed(day, lab_dir=workdir / "lab", loop=False)
    plc_port, bus_port = free_port(), free_port()
    plc = Plc(feed, plc_port, 10.0 / args.speed)
    d = DaemonProcess(write_config(workdir, bus_port, args.speed), plc_port, workdir)
    clock = Clock(args.speed)
    t_start = int(day.scans.index[0])
    faults, excused = [], []
    day_s = 86_400 / args.speed
    k = 0
    try:  # the daemon and the PLC are stopped whatever happens, also during start-up
        d.start(t_start)
        clock.started(wait_ready(d))
        plc.start()
        wall_end = time.monotonic() + args.days * day_s
        next_fault = time.monotonic() + args.fault_every * 3600 / args.speed
        while time.monotonic() < wall_end and not feed.finished:
            d.sample_rss()
            if time.monotonic() >= next_fault:
                kind = FAULTS[k % len(FAULTS)]
                k += 1
                a = clock.now_ns()
                info = inject(kind, d, plc, feed, clock, f"tcp/127.0.0.1:{bus_port}",
                              workdir, args.speed, disk)
                b = clock.now_ns()
                faults.append({"fault": kind, "plant_time_ns": a, **info})
                if kind in INTERRUPTING:
                    excused.append((a - WINDOW_NS, b + args.heal_windows * WINDOW_NS))
                next_fault += args.fault_every * 3600 / args.speed
            time.sleep(1.0)
        t_end = clock.now_ns()
        flood = None
        if args.flood:
            a = clock.now_ns()
            flood = flood_phase(d, clock, f"tcp/127.0.0.1:{bus_port}", args.flood, args.settle)
            t_end = clock.now_ns()
            # the floods take the scans' rate (all scans, whoever publishes them): the PLC's
            # scans are dropped with the flood's, so those windows are stale by design
            excused.append((a, t_end))
    finally:
        stop_s = d.stop()
        plc.close()
    ends, problems, empty, nonsense = recorded(workdir)
    excused.append((t_start, t_start + 3600 * 10**9))  # the first hour: warming up
    miss = missing_windows(ends, t_start, t_end, excused)
    mem = memory_by_day(d.rss, int(day_s))
    return {"days": args.days, "speed": args.speed, "workdir": str(workdir),
            "faults": faults, "daemon_runs": d.runs, "windows_estimated": len(ends),
            "windows_missing": len(miss), "first_missing_ns": miss[:5],
            "rss_peak_mb_by_day": mem, "tracebacks": d.tracebacks(),
            "unreadable_or_truncated_files": problems, "empty_files": empty,
            "ok_estimates_of_nonsense": nonsense[:5], "n_ok_nonsense": len(nonsense),
            "final_sigterm_s": round(stop_s, 2),
            "final_exit_code": d.proc.returncode if d.proc else None,
            **({"flood": flood} if flood is not None else {})}


def main() -> int:
    # the simulated PLC runs in this process: pymodbus's own frame dumps are not the report
    logging.basicConfig(level=logging.WARNING)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=float, default=7.0)
    ap.add_argument("--speed", type=float, default=600.0)
    ap.add_argument("--fault-every", type=float, default=6.0, help="plant hours")
    ap.add_argument("--heal-windows", type=int, default=3)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--workdir", default=None)
    ap.add_argument("--flood", type=int, default=0, help="floods after the days (0: none)")
    ap.add_argument("--settle", type=float, default=20.0,
                    help="wall seconds at rest before and after a flood")
    ap.add_argument("--flood-json", default=None, help="write the flood phase's numbers here")
    args = ap.parse_args()
    out = soak(args)
    mem = out["rss_peak_mb_by_day"]
    flood_checks = {}
    if "flood" in out:
        target = json.loads(TARGETS.read_text())["soak_memory"]
        fl = out["flood"]
        flood_checks = {
            "baseline_rss_at_most_target":
                fl["rss_baseline_mb"] <= target["baseline_rss_at_most_mb"],
            "rss_back_after_every_flood": all(
                f["after_over_baseline"] <= target["after_flood_over_baseline_at_most"]
                for f in fl["floods"]),
        }
        if args.flood_json:
            Path(args.flood_json).write_text(json.dumps(
                {"command": "python benchmarks/soak.py " + " ".join(sys.argv[1:]),
                 "speed": args.speed, "outputs": ["modbus", "prometheus", "opcua", "web"],
                 "targets": target, **fl, "checks": flood_checks}, indent=2) + "\n")
    out["checks"] = {
        "every_window_estimated_after_faults_heal": out["windows_missing"] == 0,
        "memory_flat": len(mem) < 2 or mem[-1] <= 1.25 * mem[0],
        "memory_at_most_300mb": not mem or max(mem) <= 300.0,
        "no_tracebacks": out["tracebacks"] == 0,
        # only a file a SIGKILL or the full disk cut may lack its footer (--allow-truncated)
        "every_file_readable": len(out["unreadable_or_truncated_files"])
        <= sum(f["fault"] in CUTTING for f in out["faults"]),
        "no_empty_file": not out["empty_files"],
        "no_ok_estimate_of_nonsense": out["n_ok_nonsense"] == 0,
        "clean_sigterm": out["final_exit_code"] == 0 and out["final_sigterm_s"] < 10
        and all(f.get("exit_code", 0) == 0 for f in out["faults"] if f["fault"] != "sigkill"),
        **flood_checks,
    }
    print(json.dumps(out, indent=2))
    return 0 if all(out["checks"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
