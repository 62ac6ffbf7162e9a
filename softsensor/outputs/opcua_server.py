"""The latest estimate on OPC UA (``[outputs.opcua]``), by asyncua.

An OPC UA server at ``opc.tcp://host:port/softsensor/`` holds, under ``Objects/<unit>`` in the
namespace ``urn:softsensor``, one read-only variable per value: the outlet and inlet moisture
and their standard deviations [kg/kg dry basis, Double], both moistures in % on the display
basis [Double], the window end [DateTime, UTC], the health [String] and its code [UInt16],
and whether a lab result corrected the window [Boolean]. Every numeric variable carries the
standard ``EngineeringUnits`` property (an ``EUInformation``, UNECE codes where one exists),
so a SCADA client shows the unit without configuration. A missing estimate is NaN, with the
health saying why.

The server accepts anonymous, unencrypted sessions (``None`` security policy) on loopback by
default; a plant network that needs more puts it behind the site's OPC UA gateway or sets
certificates (asyncua's ``load_certificate``), which the daemon does not manage.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any

from asyncua import Server, ua

from softsensor.display import DisplaySettings, moisture_pct
from softsensor.errors import ConfigError
from softsensor.outputs.settings import OpcUaSettings

log = logging.getLogger(__name__)

NAMESPACE = "urn:softsensor"
_UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
#: name -> (variant type, unit shown, UNECE common code or None, description)
VARIABLES: dict[str, tuple[ua.VariantType, str | None, str | None, str]] = {
    "moisture_out": (ua.VariantType.Double, "kg/kg", None,
                     "fibre moisture at the outlet, kg water per kg dry fibre"),
    "moisture_out_std": (ua.VariantType.Double, "kg/kg", None, "its standard deviation"),
    "moisture_in": (ua.VariantType.Double, "kg/kg", None,
                    "fibre moisture at the inlet, kg water per kg dry fibre"),
    "moisture_in_std": (ua.VariantType.Double, "kg/kg", None, "its standard deviation"),
    "moisture_out_pct": (ua.VariantType.Double, "%", "P1", "outlet moisture in %"),
    "moisture_in_pct": (ua.VariantType.Double, "%", "P1", "inlet moisture in %"),
    "window_end": (ua.VariantType.DateTime, None, None, "end of the estimated window (UTC)"),
    "health": (ua.VariantType.String, None, None, "ok, degraded or stale"),
    "health_code": (ua.VariantType.UInt16, None, None,
                    "0 ok, 1 degraded, 2 stale, 3 no estimate yet"),
    "lab_updated": (ua.VariantType.Boolean, None, None,
                    "a lab result corrected this window"),
}
_CODES = {"ok": 0, "degraded": 1, "stale": 2}


def _unit_id(code: str | None) -> int:
    """The UNECE common code packed as OPC UA's ``UnitId`` (Part 8, EUInformation)."""
    if code is None:
        return -1
    value = 0
    for ch in code:
        value = (value << 8) | ord(ch)
    return value


def opcua_values(body: Mapping[str, Any], time_ns: int, display: DisplaySettings
                 ) -> dict[str, Any]:
    """The variables' values for one estimate body."""
    def num(key: str) -> float:
        v = body.get(key)
        return math.nan if v is None or not math.isfinite(float(v)) else float(v)

    out: dict[str, Any] = {k: num(k) for k in ("moisture_out", "moisture_out_std",
                                                "moisture_in", "moisture_in_std")}
    basis = display.moisture_basis
    out["moisture_out_pct"] = float(moisture_pct(out["moisture_out"], basis))
    out["moisture_in_pct"] = float(moisture_pct(out["moisture_in"], basis))
    out["window_end"] = datetime.fromtimestamp(time_ns / 1e9, UTC)
    status = str(body.get("status", "stale"))
    out["health"] = status
    out["health_code"] = _CODES.get(status, 3)
    out["lab_updated"] = bool(body.get("lab_updated"))
    return out


class EstimateOpcUaServer:
    """The OPC UA server (module docstring); :meth:`publish` may be called from any thread
    once :meth:`start` has run in the daemon's event loop."""

    def __init__(self, settings: OpcUaSettings, display: DisplaySettings,
                 unit: str = "dryer1") -> None:
        self.settings, self.display, self.unit = settings, display, unit
        self.endpoint = f"opc.tcp://{settings.host}:{settings.port}/softsensor/"
        self._server: Server | None = None
        self._nodes: dict[str, Any] = {}
        self._loop: asyncio.AbstractEventLoop | None = None

    async def _variables(self, server: Server) -> None:
        idx = await server.register_namespace(NAMESPACE)
        obj = await server.nodes.objects.add_object(idx, self.unit)
        for name, (vtype, unit, code, text) in VARIABLES.items():
            start = {ua.VariantType.Double: math.nan, ua.VariantType.String: "stale",
                     ua.VariantType.UInt16: 3, ua.VariantType.Boolean: False,
                     ua.VariantType.DateTime: datetime.fromtimestamp(0, UTC)}[vtype]
            node = await obj.add_variable(idx, name, ua.Variant(start, vtype))
            await node.write_attribute(ua.AttributeIds.Description,
                                       ua.DataValue(ua.Variant(ua.LocalizedText(text))))
            if unit is not None:
                eu = ua.EUInformation(NamespaceUri=_UNECE, UnitId=_unit_id(code),
                                      DisplayName=ua.LocalizedText(unit),
                                      Description=ua.LocalizedText(text))
                await node.add_property(0, "EngineeringUnits", ua.Variant(eu))
            self._nodes[name] = (node, vtype)

    async def start(self) -> None:
        server = Server()
        await server.init()
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"softsensor {self.unit}")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        await self._variables(server)
        try:
            await server.start()
        except (OSError, RuntimeError) as exc:  # asyncua: "Could not start listen" (taken)
            raise ConfigError(f"outputs.opcua: cannot listen on {self.settings.host}:"
                              f"{self.settings.port}: "
                              f"{getattr(exc, 'strerror', None) or exc}") from exc
        self._server, self._loop = server, asyncio.get_running_loop()
        log.info("estimate served on %s", self.endpoint)

    async def _write(self, values: Mapping[str, Any]) -> None:
        for name, value in values.items():
            node, vtype = self._nodes[name]
            await node.write_value(ua.Variant(value, vtype))

    def publish(self, body: Mapping[str, Any], time_ns: int) -> None:
        """Serve a new estimate (thread-safe: handed to the server's event loop)."""
        if self._loop is not None:
            asyncio.run_coroutine_threadsafe(
                self._write(opcua_values(body, time_ns, self.display)), self._loop)

    def health(self, status: str) -> None:
        """A health change between estimates."""
        if self._loop is not None:
            asyncio.run_coroutine_threadsafe(
                self._write({"health": status, "health_code": _CODES.get(status, 3)}),
                self._loop)

    async def stop(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            with contextlib.suppress(Exception):
                await server.stop()


__all__ = ["NAMESPACE", "VARIABLES", "EstimateOpcUaServer", "opcua_values"]
