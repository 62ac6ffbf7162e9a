"""The latest estimate on OPC UA (``[outputs.opcua]``), by asyncua.

An OPC UA server at ``opc.tcp://host:port/softsensor/`` holds, under ``Objects/<unit>`` in the
namespace ``urn:softsensor``, one read-only variable per value: the outlet and inlet moisture
and their standard deviations [kg/kg dry basis], both moistures in % on the display basis,
the outlet temperatures measured and modelled [°C], the window end [DateTime, UTC], the health
[String] and its code [UInt16], and whether a lab result corrected the window [Boolean]; with
the set-point advisor on, its advice (``advice_*``: advisory only).

The numeric values are ``AnalogItemType`` variables (OPC UA Part 8) of type Double, each with
its ``EURange`` (the range a SCADA scales a bar or trend to) and ``EngineeringUnits`` (an
``EUInformation``, UNECE codes where one exists), so a client shows them without
configuration. Every value carries the end of its window as ``SourceTimestamp`` (when the
value is true, not when it was written) and a status: Good when the health is ``ok``,
Uncertain when ``degraded``, Bad when ``stale`` or missing (NaN). The values are historized
(``Historizing``, ``HistoryRead`` in the access level): a client's HistoryRead returns the last
``history_h`` hours (48) of windows, kept in memory by count, so an accelerated demo whose
clock runs ahead of the wall keeps them too.

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
from asyncua.common.instantiate_util import instantiate

from softsensor.errors import ConfigError
from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.opcua_limits import HEADROOM, OpcUaConnections, standard_space_shelf
from softsensor.outputs.settings import OpcUaSettings
from softsensor.presentation.display import DisplaySettings, moisture_pct

log = logging.getLogger(__name__)
#: A connection must have activated its session this soon [s] (a client does so at once).
PENDING_ACTIVATION_S = 10.0


class _StartNoise(logging.Filter):
    """Drops what asyncua says at WARNING while this server starts and that no operator can
    act on (about 40 lines, which buried the daemon's first line): an ``AnalogItemType``'s
    optional attributes it does not copy, and that a NoSecurity endpoint has no signing or
    encryption (said once, in the server's own start line, with what to do about it)."""

    NOISE = ("Instantiate: while copying attributes", "No signing policy available",
             "No encrypting policy available")

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(self.NOISE)


for _name in ("asyncua.common.copy_node_util", "asyncua.server.server"):
    logging.getLogger(_name).addFilter(_StartNoise())

NAMESPACE = "urn:softsensor"
_UNECE = "http://www.opcfoundation.org/UA/units/un/cefact"
#: name -> (variant type, unit shown, UNECE common code or None, EURange or None, description)
VARIABLES: dict[str, tuple[ua.VariantType, str | None, str | None, tuple[float, float] | None,
                           str]] = {
    "moisture_out": (ua.VariantType.Double, "kg/kg", None, (0.0, 2.0),
                     "fibre moisture at the outlet, kg water per kg dry fibre"),
    "moisture_out_std": (ua.VariantType.Double, "kg/kg", None, (0.0, 0.5),
                         "its standard deviation"),
    "moisture_in": (ua.VariantType.Double, "kg/kg", None, (0.0, 2.0),
                    "fibre moisture at the inlet, kg water per kg dry fibre"),
    "moisture_in_std": (ua.VariantType.Double, "kg/kg", None, (0.0, 0.5),
                        "its standard deviation"),
    "moisture_out_pct": (ua.VariantType.Double, "%", "P1", (0.0, 100.0),
                         "outlet moisture in % on the display basis"),
    "moisture_in_pct": (ua.VariantType.Double, "%", "P1", (0.0, 100.0),
                        "inlet moisture in % on the display basis"),
    "T_dryer_out_measured": (ua.VariantType.Double, "°C", "CEL", (0.0, 200.0),
                             "dryer outlet temperature, window mean of the measurement"),
    "T_dryer_out_model": (ua.VariantType.Double, "°C", "CEL", (0.0, 200.0),
                          "dryer outlet temperature, the model's"),
    "T_cyclone_out_measured": (ua.VariantType.Double, "°C", "CEL", (0.0, 200.0),
                               "cyclone outlet temperature, window mean of the measurement"),
    "T_cyclone_out_model": (ua.VariantType.Double, "°C", "CEL", (0.0, 200.0),
                            "cyclone outlet temperature, the model's"),
    "window_end": (ua.VariantType.DateTime, None, None, None,
                   "end of the estimated window (UTC)"),
    "health": (ua.VariantType.String, None, None, None, "ok, degraded or stale"),
    "health_code": (ua.VariantType.UInt16, None, None, None,
                    "0 ok, 1 degraded, 2 stale, 3 no estimate yet"),
    "lab_updated": (ua.VariantType.Boolean, None, None, None,
                    "a lab result corrected this window"),
    # the set-point advisor's (softsensor.service.advisor_tap): advisory only
    "advice_given": (ua.VariantType.Boolean, None, None, None,
                     "the advisor gives advice (else advice_reason says why not)"),
    "advice_reason": (ua.VariantType.String, None, None, None,
                      "the advice, or why there is none, in one line"),
    "advice_T_sp": (ua.VariantType.Double, "°C", "CEL", (0.0, 200.0),
                    "advised outlet-temperature set point"),
    "advice_saving_kwh_per_t": (ua.VariantType.Double, "kWh/t", None, (-200.0, 200.0),
                                "burner heat saved per tonne of dry fibre at the advised "
                                "set point"),
}
_CODES = {"ok": 0, "degraded": 1, "stale": 2}
#: The status of a value by the health of its window.
_QUALITY = {"ok": ua.StatusCodes.Good, "degraded": ua.StatusCodes.Uncertain}
#: Length of one estimator window [s]: the history is kept by count, one value a window.
WINDOW_S = 600.0


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
    for key in ("T_dryer_out_measured", "T_dryer_out_model", "T_cyclone_out_measured",
                "T_cyclone_out_model"):
        out[key] = num(key) - 273.15
    out["window_end"] = datetime.fromtimestamp(time_ns / 1e9, UTC)
    status = str(body.get("status", "stale"))
    out["health"] = status
    out["health_code"] = _CODES.get(status, 3)
    out["lab_updated"] = bool(body.get("lab_updated"))
    return out


def _data_value(value: Any, vtype: ua.VariantType, status: str,
                when: datetime | None) -> ua.DataValue:
    """A value with its status (health, NaN: Bad) and source time (its window's end)."""
    bad = isinstance(value, float) and not math.isfinite(value)
    code = ua.StatusCodes.Bad if bad else _QUALITY.get(status, ua.StatusCodes.Bad)
    if vtype != ua.VariantType.Double:
        code = ua.StatusCodes.Good  # health, window end and flags are what they say
    return ua.DataValue(ua.Variant(value, vtype), StatusCode=ua.StatusCode(code),
                        SourceTimestamp=when, ServerTimestamp=datetime.now(UTC))


class EstimateOpcUaServer:
    """The OPC UA server (module docstring), an
    :class:`~softsensor.outputs.operator_output.OperatorOutput`: :meth:`on_estimate` may be
    called from any thread once :meth:`start` has run in the daemon's event loop."""

    name = "opcua"

    def __init__(self, settings: OpcUaSettings, display: DisplaySettings,
                 unit: str = "dryer1") -> None:
        self.settings, self.display, self.unit = settings, display, unit
        self.endpoint = f"opc.tcp://{settings.host}:{settings.port}/softsensor/"
        self._server: Server | None = None
        self._nodes: dict[str, Any] = {}
        self._loop: asyncio.AbstractEventLoop | None = None

    async def _analog(self, server: Server, obj: Any, idx: int, name: str) -> Any:
        """An ``AnalogItemType`` Double variable with its EURange and EngineeringUnits."""
        _vtype, unit, code, eu_range, text = VARIABLES[name]
        node = (await instantiate(obj, server.get_node(ua.ObjectIds.AnalogItemType),
                                  bname=ua.QualifiedName(name, idx), idx=idx,
                                  instantiate_optional=False))[0]
        await node.write_attribute(ua.AttributeIds.DataType, ua.DataValue(
            ua.Variant(ua.NodeId(ua.ObjectIds.Double), ua.VariantType.NodeId)))
        assert eu_range is not None and unit is not None
        eur = await node.get_child(["0:EURange"])
        await eur.write_value(ua.Variant(ua.Range(Low=eu_range[0], High=eu_range[1]),
                                         ua.VariantType.ExtensionObject))
        eu = ua.EUInformation(NamespaceUri=_UNECE, UnitId=_unit_id(code),
                              DisplayName=ua.LocalizedText(unit),
                              Description=ua.LocalizedText(text))
        await node.add_property(0, "EngineeringUnits", ua.Variant(eu))
        return node

    async def _variables(self, server: Server) -> None:
        idx = await server.register_namespace(NAMESPACE)
        obj = await server.nodes.objects.add_object(idx, self.unit)
        start = {ua.VariantType.Double: math.nan, ua.VariantType.String: "stale",
                 ua.VariantType.UInt16: 3, ua.VariantType.Boolean: False,
                 ua.VariantType.DateTime: datetime.fromtimestamp(0, UTC)}
        for name, (vtype, _unit, _code, eu_range, text) in VARIABLES.items():
            if eu_range is not None:
                node = await self._analog(server, obj, idx, name)
            else:
                node = await obj.add_variable(idx, name, ua.Variant(start[vtype], vtype))
            await node.write_attribute(ua.AttributeIds.Description,
                                       ua.DataValue(ua.Variant(ua.LocalizedText(text))))
            waiting = (ua.StatusCodes.BadWaitingForInitialData
                       if vtype == ua.VariantType.Double else ua.StatusCodes.Good)
            await node.write_value(ua.DataValue(  # stamped: history compares the times
                ua.Variant(start[vtype], vtype), StatusCode=ua.StatusCode(waiting),
                SourceTimestamp=datetime.now(UTC), ServerTimestamp=datetime.now(UTC)))
            self._nodes[name] = (node, vtype)
        count = int(self.settings.history_h * 3600 / WINDOW_S) + 1
        await server.historize_node_data_change([n for n, _ in self._nodes.values()],
                                                period=None, count=count)

    async def start(self) -> str:
        """Serve the variables; what it serves: the endpoint."""
        server = Server()
        shelf, shelved = standard_space_shelf()  # 58 MB less resident (opcua_limits)
        await server.init(shelf)
        shelved()
        server.set_endpoint(self.endpoint)
        server.set_server_name(f"softsensor {self.unit}")
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        # asyncua's own bounds, tightened (issue 40): 1,000 connections, 30 s to activate a
        # session and sessions kept for 10 min by default
        limits = server.iserver
        # more than max_connections admitted: the sweep (opcua_limits) evicts by its rule
        limits.max_connections = self.settings.max_connections + HEADROOM
        limits.max_pending_activation_seconds = min(self.settings.idle_timeout_s,
                                                    PENDING_ACTIVATION_S)
        limits.max_session_timeout_ms = 1000 * self.settings.idle_timeout_s
        limits.min_session_timeout_ms = min(limits.min_session_timeout_ms,
                                            limits.max_session_timeout_ms)
        await self._variables(server)
        try:
            await server.start()
        except (OSError, RuntimeError) as exc:  # asyncua: "Could not start listen" (taken)
            raise ConfigError(f"outputs.opcua: cannot listen on {self.settings.host}:"
                              f"{self.settings.port}: "
                              f"{getattr(exc, 'strerror', None) or exc}") from exc
        self._server, self._loop = server, asyncio.get_running_loop()
        self.connections = OpcUaConnections(server.bserver, self.settings)
        self._sweeper = asyncio.create_task(self.connections.run(), name="opcua-connections")
        log.info("estimate served on %s (anonymous, no encryption: keep it on loopback or "
                 "behind the site's OPC UA gateway)", self.endpoint)
        return self.endpoint

    async def _write(self, values: Mapping[str, Any], status: str,
                     when: datetime | None) -> None:
        for name, value in values.items():
            node, vtype = self._nodes[name]
            await node.write_value(_data_value(value, vtype, status, when))

    def on_estimate(self, estimate: Estimate) -> None:
        """Serve a new estimate (thread-safe: handed to the server's event loop), stamped
        with the end of its window."""
        if self._loop is not None:
            values = opcua_values(estimate.to_body(), estimate.time_ns, self.display)
            asyncio.run_coroutine_threadsafe(
                self._write(values, values["health"], values["window_end"]), self._loop)

    def on_health(self, health: Health) -> None:
        """A health change between estimates (stamped now)."""
        status = health.status
        if self._loop is not None:
            asyncio.run_coroutine_threadsafe(
                self._write({"health": status, "health_code": _CODES.get(status, 3)}, status,
                            datetime.now(UTC)), self._loop)

    def on_advice(self, advice: Any) -> None:
        """Serve the advisor's latest (an :class:`~softsensor.advisor.advice.Advice`),
        stamped with the end of its window."""
        if self._loop is not None:
            values = {"advice_given": bool(advice.advised), "advice_reason": str(advice.reason),
                      "advice_T_sp": math.nan if advice.T_sp_advised is None
                      else advice.T_sp_advised - 273.15,
                      "advice_saving_kwh_per_t": math.nan if advice.saving_kwh_per_t is None
                      else float(advice.saving_kwh_per_t)}
            asyncio.run_coroutine_threadsafe(self._write(
                values, "ok", datetime.fromtimestamp(advice.time_ns / 1e9, UTC)), self._loop)

    def on_lab(self, lab: LabResult) -> None:
        """Lab results are not served as variables."""

    async def stop(self) -> None:
        server, self._server = self._server, None
        sweeper, self._sweeper = getattr(self, "_sweeper", None), None
        if sweeper is not None:
            sweeper.cancel()
        if server is not None:
            with contextlib.suppress(Exception):
                await server.stop()


__all__ = ["NAMESPACE", "VARIABLES", "WINDOW_S", "EstimateOpcUaServer", "opcua_values"]
