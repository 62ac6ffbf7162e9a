"""Where operators look: one interface for the web page, Modbus, OPC UA and Prometheus.

The daemon hands every estimate, health and lab result it publishes to each running
:class:`OperatorOutput`, in the order it publishes them: estimates and health from the
estimator's thread (or, for the watchdog's and the recorder's news, the daemon's loop, one at a
time with the estimator's), lab results from the lab input's. An output hands the work to its
own server's thread or loop and returns at once. :func:`operator_outputs`
builds the ones the ``[outputs.*]`` tables enable, each with its settings given to its
constructor; the daemon starts them, fans out to them in one loop and stops them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Protocol

from softsensor.estimate import Estimate, Health
from softsensor.messages import LabResult
from softsensor.outputs.metrics import DaemonMetrics
from softsensor.outputs.modbus_server import ABUSE_COUNTERS, EstimateModbusServer
from softsensor.outputs.settings import OutputSettings
from softsensor.outputs.web import LivePage
from softsensor.presentation.display import DisplaySettings


class OperatorOutput(Protocol):
    """What the daemon needs of an operator output (module docstring)."""

    #: The ``[outputs.<name>]`` table it serves.
    name: str

    async def start(self) -> str:
        """Start serving (in the daemon's event loop); what it serves (a URL). A port in use
        is a one-line :class:`~softsensor.errors.ConfigError` naming the table."""
        ...

    async def stop(self) -> None:
        """Stop serving (idempotent)."""
        ...

    def on_estimate(self, estimate: Estimate) -> None:
        """Serve a new estimate (from any thread)."""
        ...

    def on_health(self, health: Health) -> None:
        """A new health (between estimates too)."""
        ...

    def on_lab(self, lab: LabResult) -> None:
        """A lab result the daemon published."""
        ...


def operator_outputs(settings: OutputSettings, display: DisplaySettings, unit: str, *,
                     clock: Callable[[], int], time_scale: float,
                     counters: Mapping[str, tuple[str, Callable[[], float]]],
                     tick_seconds: Callable[[], float | None]) -> list[OperatorOutput]:
    """The outputs the tables enable, in the order they start: Modbus, Prometheus, OPC UA,
    the web page. ``clock``: the plant's clock [ns]; ``time_scale``: plant seconds per wall
    second; ``counters``: the daemon's counters for Prometheus (name -> help, reader);
    ``tick_seconds``: the wall time of the last tick [s]."""
    out: list[OperatorOutput] = []
    if settings.modbus.enabled:
        modbus = EstimateModbusServer(settings.modbus, display)
        out.append(modbus)
        counters = {**counters, **modbus_counters(modbus)}
    if settings.prometheus.enabled:
        out.append(DaemonMetrics(settings.prometheus, counters, unit=unit, display=display,
                                 tick_seconds=tick_seconds))
    if settings.opcua.enabled:
        # asyncua takes a second to import: only a daemon that serves OPC UA pays it
        from softsensor.outputs.opcua_server import EstimateOpcUaServer

        out.append(EstimateOpcUaServer(settings.opcua, display, unit))
    if settings.web.enabled:
        out.append(LivePage(settings.web, display, unit, clock=clock, time_scale=time_scale))
    return out


def lab_refused(forget: Callable[[str], None], outputs: Mapping[str, OperatorOutput]
                ) -> Callable[[str], None]:
    """What the estimator service calls with the sample id of a lab result it refused:
    ``forget`` it (the lab input's or the lab folder's: a corrected result with that id is
    then taken, in the folder's ``.seen-ids`` too), then tell each output that marks refused
    results (``on_lab_refused``: the live page, whose "Last lab result" is the last one taken,
    issue 49)."""
    def refused(sample_id: str) -> None:
        forget(sample_id)
        for output in outputs.values():
            tell = getattr(output, "on_lab_refused", None)
            if tell is not None:
                tell(sample_id)
    return refused


def modbus_counters(server: EstimateModbusServer
                    ) -> dict[str, tuple[str, Callable[[], float]]]:
    """The Modbus server's abuse counters for Prometheus (``softsensor_modbus_<name>``)."""
    return {f"softsensor_modbus_{name}": (text, lambda name=name: getattr(server, name))
            for name, text in ABUSE_COUNTERS.items()}


def abuse(outputs: Mapping[str, OperatorOutput]) -> dict[str, dict[str, int]]:
    """What the outputs refused or closed, by output and counter (for health)."""
    return {name: o.abuse() for name, o in outputs.items() if hasattr(o, "abuse")}


__all__ = ["OperatorOutput", "abuse", "lab_refused", "modbus_counters", "operator_outputs"]
