"""Real clients for the daemon's servers, shared by the tests that read them: Prometheus'
own text parser for ``/metrics``, a headless Chromium for the live page, an asyncua client
for the OPC UA server and a pymodbus client for the Modbus registers."""

from __future__ import annotations

import shutil
import struct
import subprocess
import urllib.request
from datetime import UTC, datetime, timedelta

import pytest
from asyncua import Client, ua
from prometheus_client.parser import text_string_to_metric_families
from pymodbus.client import AsyncModbusTcpClient

from softsensor.outputs.modbus_server import N_REGISTERS, REGISTERS
from softsensor.outputs.opcua_server import NAMESPACE


def scrape_metrics(port: int, unit: str = "dryer1", site: str = "plant") -> dict[str, float]:
    """Every sample of ``/metrics`` by name and labels; each must carry the ``dryer`` and
    ``site`` labels, and ``unit`` (deprecated) equal to ``dryer`` (left out of the key)."""
    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            labels = dict(s.labels)
            assert (labels.pop("dryer", None), labels.pop("site", None),
                    labels.pop("unit", None)) == (unit, site, unit), s
            key = s.name + ("" if not labels else str(sorted(labels.items())))
            out[key] = s.value
    return out


def browser() -> str:
    """The headless Chromium's path; the test is skipped, saying what to install, without."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        pytest.skip("headless Chromium is not installed (apt install chromium)")
    return found


#: Chromium's flags for a closed network: no background connections, no first-run pages.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-default-apps", "--disable-extensions", "--disable-sync",
                  "--no-first-run", "--mute-audio", "--hide-scrollbars", "--window-size=1050,1500"]


def chromium(url: str, *extra: str) -> subprocess.CompletedProcess:
    """Headless Chromium run on ``url`` with ``extra`` flags (``--dump-dom``,
    ``--screenshot=...``); its completed process."""
    return subprocess.run([browser(), *CHROMIUM_FLAGS, *extra, url], capture_output=True,
                          text=True, timeout=90)


def chromium_dom(url: str) -> str:
    """The page's DOM after Chromium rendered it (it must hold an SVG chart)."""
    r = chromium(url, "--dump-dom")
    assert "<svg" in r.stdout, r.stderr[-2000:]
    return r.stdout


async def opcua_read(endpoint: str, names: list[str], history_end: datetime | None = None,
                     write: bool = False) -> dict:
    """Values, data types and data values of the ``dryer1`` items ``names`` read by an asyncua
    client; for ``moisture_out`` also its type, unit, range, history flags and (with
    ``history_end``) the 48 h of history before it; ``write`` tries a write and says how it
    ended."""
    async with Client(endpoint, timeout=5) as client:
        idx = await client.get_namespace_index(NAMESPACE)
        obj = await client.nodes.objects.get_child([f"{idx}:dryer1"])
        out = {}
        for n in names:
            node = await obj.get_child([f"{idx}:{n}"])
            dv = await node.read_data_value(raise_on_bad_status=False)
            out[n] = (dv.Value.Value, await node.read_data_type_as_variant_type())
            out[n + ":dv"] = dv
            if n == "moisture_out":
                out["type"] = await node.read_type_definition()
                eu = await node.get_child(["0:EngineeringUnits"])
                out["eu"] = (await eu.read_value()).DisplayName.Text
                rng = await (await node.get_child(["0:EURange"])).read_value()
                out["range"] = (rng.Low, rng.High)
                out["historizing"] = (await node.read_attribute(
                    ua.AttributeIds.Historizing)).Value.Value
                access = (await node.read_attribute(ua.AttributeIds.AccessLevel)).Value.Value
                out["history_read"] = bool(access & (1 << ua.AccessLevel.HistoryRead))
                if history_end is not None:
                    history = await node.read_raw_history(history_end - timedelta(hours=48),
                                                          history_end)
                    out["history"] = [(d.SourceTimestamp.replace(tzinfo=UTC), d.Value.Value)
                                      for d in history]
                if write:
                    try:
                        await node.write_value(ua.Variant(0.5, ua.VariantType.Double))
                        out["write"] = "accepted"
                    except ua.UaStatusCodeError as exc:
                        out["write"] = type(exc).__name__
        return out


async def modbus_read(port: int, write: bool = False):
    """The estimate's input registers read by pymodbus from ``127.0.0.1:port``; with ``write``
    also the answers to a register write and a holding-register read (both must be refused):
    ``(registers, write answer, holding answer)``."""
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
    await client.connect()
    try:
        rr = await client.read_input_registers(0, count=N_REGISTERS, device_id=1)
        assert not rr.isError(), rr
        wr = await client.write_register(0, 5, device_id=1) if write else None
        hr = await client.read_holding_registers(0, count=1, device_id=1) if write else None
        return rr.registers, wr, hr
    finally:
        client.close()


def register_float(words: list[int], name: str) -> float:
    """The float32 at register ``name`` of the estimate's layout, high word first."""
    a = REGISTERS[name][0]
    return struct.unpack(">f", struct.pack(">HH", *words[a:a + 2]))[0]


__all__ = ["CHROMIUM_FLAGS", "browser", "chromium", "chromium_dom", "modbus_read", "opcua_read",
           "register_float", "scrape_metrics"]
