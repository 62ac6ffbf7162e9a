"""The estimate on OPC UA (``[outputs.opcua]``, issues 13 and 24 item 6), read by an asyncua
client on 127.0.0.1: AnalogItemType variables with EURange and EngineeringUnits, each value
stamped with the end of its window and a status from the health, HistoryRead over the last
48 h, writes refused."""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from datetime import UTC, datetime

import pytest
from asyncua import ua
from clients import opcua_read

from softsensor.bus.zenoh_bus import free_port
from softsensor.estimate import Estimate
from softsensor.outputs.opcua_server import EstimateOpcUaServer
from softsensor.outputs.settings import OpcUaSettings
from softsensor.presentation.display import DisplaySettings

BODY = {"moisture_out": 0.1034, "moisture_out_std": 0.0042, "moisture_in": 1.0312,
        "moisture_in_std": 0.021, "status": "degraded", "lab_updated": True,
        "T_dryer_out_measured": 348.65, "T_dryer_out_model": 348.15}
T_NS = 1_767_607_800 * 10**9
W_NS = 600 * 10**9




def _utc(ns: int) -> datetime:
    return datetime.fromtimestamp(ns / 1e9, UTC)


def test_an_asyncua_client_reads_analog_items_with_source_times_and_history():
    server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=free_port()),
                                 DisplaySettings(moisture_basis="wet"))
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    def run(coro, timeout=30.0):
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout)

    names = ["moisture_out", "moisture_in_pct", "T_dryer_out_measured", "window_end",
             "health", "health_code", "lab_updated"]
    try:
        run(server.start())
        before = run(opcua_read(server.endpoint, names, _utc(T_NS + 10 * W_NS)))
        assert before["moisture_out"][0] is None or math.isnan(before["moisture_out"][0])
        assert before["health_code"][0] == 3 and before["health"][0] == "stale"
        assert before["moisture_out:dv"].StatusCode.value == \
            ua.StatusCodes.BadWaitingForInitialData
        # three windows, published from this thread as the estimator's, 10 min apart
        for k, x in enumerate((0.101, 0.102, 0.1034)):
            server.on_estimate(Estimate.from_body({**BODY, "moisture_out": x,
                                                   "window_end_ns": T_NS + k * W_NS}))
            run(asyncio.sleep(0.1))
        got = before
        for _ in range(100):  # bounded: the writes are handed to the server's loop
            got = run(opcua_read(server.endpoint, names, _utc(T_NS + 10 * W_NS), write=True))
            if got["health"][0] == "degraded" and len(got["history"]) == 3:
                break
        assert got["type"] == ua.NodeId(ua.ObjectIds.AnalogItemType)
        assert got["moisture_out"] == (pytest.approx(0.1034), ua.VariantType.Double)
        assert got["eu"] == "kg/kg" and got["range"] == (0.0, 2.0)
        dv = got["moisture_out:dv"]
        # the value is as of its window's end, not of the write; degraded: Uncertain
        assert dv.SourceTimestamp.replace(tzinfo=UTC) == _utc(T_NS + 2 * W_NS)
        assert dv.StatusCode.value == ua.StatusCodes.Uncertain
        assert got["historizing"] is True and got["history_read"]
        assert got["history"] == [(_utc(T_NS + k * W_NS), pytest.approx(x))
                                  for k, x in enumerate((0.101, 0.102, 0.1034))]
        assert got["moisture_in_pct"][0] == pytest.approx(100 * 1.0312 / 2.0312)
        assert got["T_dryer_out_measured"][0] == pytest.approx(75.5)
        assert got["window_end"][0].replace(tzinfo=UTC) == _utc(T_NS + 2 * W_NS)
        assert got["health"] == ("degraded", ua.VariantType.String)
        assert got["health_code"] == (1, ua.VariantType.UInt16)
        assert got["lab_updated"] == (True, ua.VariantType.Boolean)
        assert got["write"] != "accepted", got["write"]
    finally:
        run(server.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


def test_the_opcua_server_starts_without_forty_warning_lines(caplog):
    """asyncua said about 40 WARNING lines at every start (optional attributes of the analog
    items, and that NoSecurity has no signing), burying the daemon's first line. They are
    dropped; the server's own line says what the security note meant, and an asyncua client
    still reads the items."""
    from softsensor.outputs.opcua_server import EstimateOpcUaServer
    from softsensor.outputs.settings import OpcUaSettings

    async def main():
        server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=free_port()),
                                     DisplaySettings(), "dryer1")
        await server.start()
        try:
            return await opcua_read(server.endpoint, ["health"])
        finally:
            await server.stop()

    caplog.set_level(logging.INFO)
    got = asyncio.run(asyncio.wait_for(main(), 60))
    assert got["health"][0] is not None
    noise = [r for r in caplog.records if r.name.startswith(("asyncua.common", "asyncua.server"))
             and r.levelno >= logging.WARNING]
    assert noise == [], [r.getMessage()[:100] for r in noise[:3]]
    assert any("anonymous, no encryption" in r.getMessage() for r in caplog.records)



def test_connections_are_capped_and_idle_ones_bounded_in_time():
    """Issue 40: asyncua kept 1,000 connections, 30 s before a session is activated and
    sessions 10 min; the output's ``max_connections`` and ``idle_timeout_s`` now bound them."""
    import socket

    server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=free_port(),
                                               max_connections=4, idle_timeout_s=6),
                                 DisplaySettings())
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    def run(coro, timeout=30.0):
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout)

    held = []
    try:
        run(server.start())
        limits = server._server.iserver
        assert (limits.max_pending_activation_seconds, limits.max_session_timeout_ms) == \
            (6, 6000)
        for _ in range(10):
            held.append(socket.create_connection(("127.0.0.1", server.settings.port),
                                                 timeout=5))
        closed = 0
        for s in held:
            s.settimeout(0.3)
            try:
                closed += s.recv(1) == b""
            except TimeoutError:
                pass
            except ConnectionResetError:
                closed += 1
        assert closed == 6  # four hold their slots until their activation deadline
    finally:
        for s in held:
            s.close()
        run(server.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()


class _ServerThread:
    """The OPC UA output on its own loop and thread, as in the daemon."""

    def __init__(self, **settings):
        self.server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=free_port(),
                                                        **settings), DisplaySettings())
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)

    def run(self, coro, timeout=30.0):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def __enter__(self):
        self.thread.start()
        self.run(self.server.start())
        return self

    def __exit__(self, *exc):
        self.run(self.server.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


async def _read_twice(endpoint: str) -> list:
    """The health read by one session twice, a second apart (the sweep has run between)."""
    from asyncua import Client

    from softsensor.outputs.opcua_server import NAMESPACE

    async with Client(endpoint, timeout=5) as client:
        idx = await client.get_namespace_index(NAMESPACE)
        node = await client.nodes.objects.get_child([f"{idx}:dryer1", f"{idx}:health"])
        first = await node.read_value()
        await asyncio.sleep(1.0)
        return [first, await node.read_value()]


def test_connections_held_by_a_stranger_do_not_lock_a_client_out():
    """Issue 49 (fifth probe): asyncua's cap refused the 33rd client and evicted no one, so
    32 connections from anyone locked every other client out (0 of 36 fresh reads); now the
    address holding the most gives one up, as on the Modbus output."""
    import socket

    with _ServerThread(max_connections=4) as t:
        port = t.server.settings.port
        held = [socket.create_connection(("127.0.0.1", port), timeout=5,
                                         source_address=("127.0.0.3", 0)) for _ in range(4)]
        try:
            reads = asyncio.run(asyncio.wait_for(_read_twice(t.server.endpoint), 30))
            assert all(r is not None for r in reads), reads
            assert t.server.connections.evicted == 1  # one of the stranger's four
        finally:
            for s in held:
                s.close()


def test_the_plant_clients_of_the_opcua_output_keep_their_slots():
    import socket

    with _ServerThread(max_connections=2, plant_clients=("127.0.0.2",)) as t:
        port = t.server.settings.port
        plant = [socket.create_connection(("127.0.0.1", port), timeout=5,
                                          source_address=("127.0.0.2", 0)) for _ in range(2)]
        try:
            import time
            time.sleep(0.5)
            with socket.create_connection(("127.0.0.1", port), timeout=5,
                                          source_address=("127.0.0.3", 0)) as stranger:
                stranger.settimeout(2.0)
                assert stranger.recv(1) == b""  # closed: only plant clients hold the slots
            for s in plant:
                s.settimeout(0.5)
                with pytest.raises(TimeoutError):
                    s.recv(1)  # still open
            assert t.server.connections.refused_connections == 1
        finally:
            for s in plant:
                s.close()


def test_a_timed_out_session_has_its_connection_closed():
    """Issue 49 (fifth probe): a session asyncua timed out at 60 s kept its TCP connection
    past 90 s; now it is closed with the session."""
    from asyncua import Client

    async def silent_session(endpoint: str) -> tuple[bool, float]:
        client = Client(endpoint, timeout=5)
        await client.connect()
        for name in ("_monitor_server_task", "_renew_channel_task", "_supervisor_task",
                     "_stale_watchdog_task"):  # the client goes silent, its socket open
            task = getattr(client, name, None)
            if task is not None:
                task.cancel()
        reader = client.uaclient.protocol.transport
        t0 = asyncio.get_running_loop().time()
        while asyncio.get_running_loop().time() - t0 < 15:
            if reader.is_closing():
                return True, asyncio.get_running_loop().time() - t0
            await asyncio.sleep(0.1)
        return False, 15.0

    with _ServerThread(idle_timeout_s=5) as t:
        closed, after = asyncio.run(asyncio.wait_for(silent_session(t.server.endpoint), 60))
    assert closed and after < 9, (closed, after)


def test_the_standard_address_space_is_shelved_and_read_lazily(tmp_path):
    """Issue 49 (fifth probe, 383 MB at rest with the four outputs): asyncua built its
    standard address space in memory at every start (about 58 MB); the first start now
    shelves it on disk and later starts read nodes from the shelf as they are asked for."""
    from softsensor.outputs.opcua_limits import standard_space_shelf

    first, done = standard_space_shelf(tmp_path)
    assert first is not None and "tmp-" in first.parent.name

    async def start_and_read(shelf):
        from asyncua import Server

        server = Server()
        await server.init(shelf)
        return len(server.iserver.aspace._nodes.cache) if hasattr(
            server.iserver.aspace._nodes, "cache") else None

    assert asyncio.run(start_and_read(first)) is None  # built in memory, shelved
    done()
    second, done2 = standard_space_shelf(tmp_path)
    assert second is not None and second.is_file() and "tmp-" not in second.parent.name
    cached = asyncio.run(start_and_read(second))
    done2()
    assert cached is not None and cached < 1000  # lazily: the nodes asked for only
    assert not list(tmp_path.glob("*.tmp-*"))
