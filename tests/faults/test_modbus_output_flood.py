"""Fault injection (issue 49, the fifth probe): a flood of valid reads on the Modbus output
must not starve the PLC poller that shares the daemon's event loop, nor the DCS's reads.

Before: the server parsed each 256 kB read of requests in one go on the daemon's one event
loop; four clients sending such reads dropped the PLC scans from 6.0/s to 0-0.2/s and 12 of 12
DCS reads failed. Now each connection is answered at most a budget of requests per loop turn
and at most ``max_requests_per_s`` a second (beyond, its socket is not read until its turn).

The flooders run in a child process (their Python must not share the test's interpreter
lock); the simulated PLC on its own thread and loop, as a PLC is its own device; the poller
and the register server on one loop, as in the daemon.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import subprocess
import sys
import threading
import time

from softsensor.ingest.modbus_poller import ModbusPoller
from softsensor.ingest.tagmap import load_tagmap
from softsensor.outputs.modbus_protocol import frame
from softsensor.outputs.modbus_server import N_REGISTERS, EstimateModbusServer
from softsensor.outputs.settings import ModbusOutputSettings
from softsensor.plant.plc_server import NOMINAL_VALUES, PlcServer, constant_values
from softsensor.presentation.display import DisplaySettings

#: The poller's period in this test [s] (10 scans a second when nothing starves it).
PERIOD_S = 0.1
FLOOD_S = 3.0

#: A child process: N connections each sending 256 kB reads of valid requests as fast as
#: the server takes them and reading every answer, for a given time.
FLOODER = r"""
import socket, struct, sys, threading, time
port, n, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
one = struct.pack(">HHHBBHH", 1, 0, 6, 1, 4, 0, 17)
blob = one * (256 * 1024 // len(one))
end = time.monotonic() + seconds
def flood():
    s = socket.create_connection(("127.0.0.1", port))
    s.settimeout(0.5)
    def drain():
        while time.monotonic() < end:
            try:
                if not s.recv(1 << 16):
                    return
            except OSError:
                if time.monotonic() >= end:
                    return
    threading.Thread(target=drain, daemon=True).start()
    while time.monotonic() < end:
        try:
            s.sendall(blob)
        except socket.timeout:
            continue
        except OSError:
            return
threads = [threading.Thread(target=flood) for _ in range(n)]
for t in threads: t.start()
print("flooding", flush=True)
for t in threads: t.join()
"""


class _LoopThread:
    def __enter__(self):
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        return self

    def run(self, coro, timeout=10.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def __exit__(self, *exc):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


def _dcs_read(port: int, tid: int, timeout_s: float) -> bool:
    """One DCS poll on a fresh connection: True when answered with the block in time."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as s:
            s.sendall(frame(tid, 1, struct.pack(">BHH", 4, 0, N_REGISTERS)))
            head = s.recv(7, socket.MSG_WAITALL)
            body = s.recv(2 + 2 * N_REGISTERS, socket.MSG_WAITALL)
    except OSError:
        return False
    return len(head) == 7 and struct.unpack(">H", head[:2])[0] == tid \
        and body[:2] == bytes([4, 2 * N_REGISTERS])


def test_a_flood_of_valid_reads_starves_neither_the_plc_poller_nor_the_dcs():
    tm = load_tagmap()
    with _LoopThread() as plc_loop, _LoopThread() as daemon_loop:
        plc = PlcServer(tm, constant_values(NOMINAL_VALUES), period_s=0.5)
        plc_loop.run(plc.start())
        server = EstimateModbusServer(ModbusOutputSettings(enabled=True, port=0),
                                      DisplaySettings())
        daemon_loop.run(server.start())
        poller = daemon_loop.run(_poller(tm.with_endpoint("127.0.0.1", plc.port)))
        stop = asyncio.Event()
        poll = asyncio.run_coroutine_threadsafe(poller.run(stop), daemon_loop.loop)
        flooder = None
        try:
            time.sleep(1.0)  # connected and scanning
            assert poller.stats.scans >= 3, "the poller did not start"
            flooder = subprocess.Popen([sys.executable, "-c", FLOODER, str(server.port), "4",
                                        str(FLOOD_S + 2.0)], stdout=subprocess.PIPE, text=True)
            assert flooder.stdout.readline().strip() == "flooding"
            time.sleep(0.5)  # the flood under way
            scans0, failed0, t0 = poller.stats.scans, poller.stats.read_failures, \
                time.monotonic()
            dcs = []
            while time.monotonic() - t0 < FLOOD_S:
                dcs.append(_dcs_read(server.port, len(dcs) + 1, timeout_s=2.0))
                time.sleep(0.25)
            took = time.monotonic() - t0
            scans = poller.stats.scans - scans0
            failed = poller.stats.read_failures - failed0
            still_flooding = flooder.poll() is None
        finally:
            if flooder is not None:
                flooder.kill()
                flooder.wait(10)
                flooder.stdout.close()
            daemon_loop.loop.call_soon_threadsafe(stop.set)
            with contextlib.suppress(Exception):
                poll.result(15)
            daemon_loop.run(server.stop(), timeout=15)
            plc_loop.run(plc.stop())
    assert still_flooding
    # generous: a third of the nominal scan rate, every DCS read but one
    assert scans >= took / PERIOD_S / 3, (scans, took)
    assert failed <= 1, failed
    assert sum(dcs) >= len(dcs) - 1, dcs


async def _poller(tm) -> ModbusPoller:
    """The poller, made in the loop that runs it (pymodbus' client binds to it)."""
    return ModbusPoller(tm.with_settings(poll_period_s=PERIOD_S, timeout_s=1.0, retries=0),
                        _no_sink)


async def _no_sink(time_ns, body, quality) -> None:
    return None
