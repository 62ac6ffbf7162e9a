"""The estimate on OPC UA (``[outputs.opcua]``, issue 13), read by an asyncua client on
127.0.0.1: typed variables with engineering units, the values published, writes refused."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
from datetime import UTC, datetime

import pytest
from asyncua import Client, ua

from softsensor.display import DisplaySettings
from softsensor.outputs.opcua_server import NAMESPACE, EstimateOpcUaServer
from softsensor.outputs.settings import OpcUaSettings

BODY = {"moisture_out": 0.1034, "moisture_out_std": 0.0042, "moisture_in": 1.0312,
        "moisture_in_std": 0.021, "status": "degraded", "lab_updated": True}
T_NS = 1_767_607_800 * 10**9


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _read(endpoint: str, names: list[str], write: bool = False) -> dict:
    async with Client(endpoint, timeout=5) as client:
        idx = await client.get_namespace_index(NAMESPACE)
        obj = await client.nodes.objects.get_child([f"{idx}:dryer1"])
        out = {}
        for n in names:
            node = await obj.get_child([f"{idx}:{n}"])
            out[n] = (await node.read_value(), await node.read_data_type_as_variant_type())
            if n == "moisture_out":
                eu = await node.get_child(["0:EngineeringUnits"])
                out["eu"] = (await eu.read_value()).DisplayName.Text
                if write:
                    try:
                        await node.write_value(ua.Variant(0.5, ua.VariantType.Double))
                        out["write"] = "accepted"
                    except ua.UaStatusCodeError as exc:
                        out["write"] = type(exc).__name__
        return out


def test_an_asyncua_client_reads_typed_values_with_units_and_cannot_write():
    server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=_free_port()),
                                 DisplaySettings(moisture_basis="wet"))
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    def run(coro, timeout=30.0):
        return asyncio.run_coroutine_threadsafe(coro, loop).result(timeout)

    names = ["moisture_out", "moisture_in_pct", "window_end", "health", "health_code",
             "lab_updated"]
    try:
        run(server.start())
        before = run(_read(server.endpoint, names))
        assert math.isnan(before["moisture_out"][0]) and before["health_code"][0] == 3
        server.publish(BODY, T_NS)  # from this thread, as the estimator's
        got = before
        for _ in range(100):  # bounded: the write is handed to the server's loop
            got = run(_read(server.endpoint, names, write=True))
            if got["health"][0] == "degraded":
                break
        assert got["moisture_out"] == (pytest.approx(0.1034), ua.VariantType.Double)
        assert got["moisture_in_pct"][0] == pytest.approx(100 * 1.0312 / 2.0312)
        assert got["window_end"][0].replace(tzinfo=UTC) == datetime.fromtimestamp(
            T_NS / 1e9, UTC)
        assert got["health"] == ("degraded", ua.VariantType.String)
        assert got["health_code"] == (1, ua.VariantType.UInt16)
        assert got["lab_updated"] == (True, ua.VariantType.Boolean)
        assert got["eu"] == "kg/kg"
        assert got["write"] != "accepted", got["write"]
    finally:
        run(server.stop())
        loop.call_soon_threadsafe(loop.stop)
        thread.join(10)
        loop.close()
