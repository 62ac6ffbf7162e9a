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
        assert closed == 6  # the first four hold their slots until their activation deadline
    finally:
        for s in held:
            s.close()
        run(server.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()
