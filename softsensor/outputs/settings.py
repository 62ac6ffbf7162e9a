"""The ``[outputs.*]`` tables of the plant config: one frozen dataclass per table, validated by
:func:`softsensor.configfile.build_section` (unknown keys refused, errors naming the key).

Example ``config/dryer1.toml`` fragment::

    [outputs.modbus]        # the latest estimate as input registers (docs/interface.md s. 7)
    enabled = true
    host = "0.0.0.0"        # loopback by default; the DCS network interface here
    port = 1502
    unit_id = 1

    [outputs.prometheus]    # http://host:port/metrics
    enabled = true
    port = 9108
    site = "mill-north"     # the ``site`` label of every metric (``unit`` is the unit)

    [outputs.opcua]         # opc.tcp://host:port/softsensor/, typed, with engineering units
    enabled = true

    [outputs.web]           # http://host:port/: the last 48 h for the control room
    enabled = true
    port = 8050
    diagnosis = "reports/latest.json"   # shown when present (softsensor diagnose --json)
    workers = 8             # threads answering; 32 more connections wait, the rest are closed
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass

from softsensor.configfile import num
from softsensor.plantconfig import PlantConfig, section_of


def _addresses_problem(addresses: tuple[str, ...]) -> str | None:
    """What is wrong with ``plant_clients`` (each an IPv4 or IPv6 address), or None."""
    for i, a in enumerate(addresses):
        try:
            ipaddress.ip_address(a)
        except ValueError:
            return f"plant_clients[{i}] must be an IP address, got {a!r}"
    return None


@dataclass(frozen=True)
class ModbusOutputSettings:
    """``[outputs.modbus]``: a Modbus TCP server of the latest estimate (read-only)."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 1502
    unit_id: int = 1
    # a connection without a request this long is closed [s] (a DCS polls every few seconds)
    idle_timeout_s: float = num(60.0, gt=0, le=3600)
    # connections open at once; a new one closes the one idle longest
    max_connections: int = num(32, ge=1, le=1024)
    # requests answered per second and connection at most (10 s of them at once); a DCS
    # reads the block every few seconds, a flood waits its turn
    max_requests_per_s: float = num(100.0, gt=0, le=100_000)
    # IP addresses of the plant's own clients (the DCS): their connections are never closed
    # to make room for another address's, which is refused when only theirs are open
    plant_clients: tuple[str, ...] = ()

    def check(self) -> str | None:
        if not 0 <= self.port <= 65535:
            return f"port must be in 0..65535 (0: any free port), got {self.port}"
        if not 1 <= self.unit_id <= 247:
            return f"unit_id must be in 1..247, got {self.unit_id}"
        return _addresses_problem(self.plant_clients)


@dataclass(frozen=True)
class MetricsSettings:
    """``[outputs.prometheus]``: Prometheus metrics over HTTP (``/metrics``)."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 9108
    site: str = "plant"  # the label ``site`` of every metric (a dashboard chooses by it)
    # as [outputs.web]: threads answering, connections beyond them, header deadline [s]
    workers: int = num(2, ge=1, le=64)
    backlog: int = num(14, ge=0, le=1024)
    timeout_s: float = num(10.0, gt=0, le=300)

    def check(self) -> str | None:
        if not 0 <= self.port <= 65535:
            return f"port must be in 0..65535 (0: any free port), got {self.port}"
        return None


@dataclass(frozen=True)
class OpcUaSettings:
    """``[outputs.opcua]``: an OPC UA server of the latest estimate (read-only variables)."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 4840
    history_h: float = num(48.0, gt=0, le=24 * 31)  # HistoryRead: the last hours of windows
    # connections open at once (asyncua refuses more); a connection without a session after
    # min(idle_timeout_s, 10 s) is closed, and a session idle for idle_timeout_s [s]
    max_connections: int = num(32, ge=1, le=1024)
    idle_timeout_s: float = num(60.0, ge=5, le=3600)
    # as [outputs.modbus]: the plant's own clients, whose connections a stranger's never
    # displaces (beyond max_connections the address holding most gives one up)
    plant_clients: tuple[str, ...] = ()

    def check(self) -> str | None:
        if not 1 <= self.port <= 65535:
            return f"port must be in 1..65535, got {self.port}"
        return _addresses_problem(self.plant_clients)


@dataclass(frozen=True)
class WebSettings:
    """``[outputs.web]``: the live page for the control room (``http://host:port/``)."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 8050
    history_h: float = 48.0  # hours of estimates and lab results the page shows
    refresh_s: float = 30.0  # the browser reloads the page this often [s, wall]
    diagnosis: str | None = None  # REPORT.json of `softsensor diagnose --json` to show
    workers: int = num(8, ge=1, le=64)  # threads drawing answers (/healthz needs none)
    # connections open at once: workers + backlog; a new one closes the oldest still sending
    # its header, or is closed when all are being answered
    backlog: int = num(32, ge=0, le=1024)
    # deadline for a request's whole header from its connection (trickling bytes does not
    # extend it), and for the client to take the answer [s]
    timeout_s: float = num(10.0, gt=0, le=300)

    def check(self) -> str | None:
        if not 0 <= self.port <= 65535:
            return f"port must be in 0..65535 (0: any free port), got {self.port}"
        if not 0 < self.history_h <= 24 * 31:
            return f"history_h must be in (0, 744], got {self.history_h}"
        if not 1 <= self.refresh_s <= 3600:
            return f"refresh_s must be in [1, 3600], got {self.refresh_s}"
        return None


@dataclass(frozen=True)
class OutputSettings:
    """``[outputs]``: one sub-table per output (absent ones: their defaults, off)."""

    modbus: ModbusOutputSettings = ModbusOutputSettings()
    prometheus: MetricsSettings = MetricsSettings()
    web: WebSettings = WebSettings()
    opcua: OpcUaSettings = OpcUaSettings()


def output_settings(cfg: PlantConfig) -> OutputSettings:
    """The validated ``[outputs.*]`` tables of ``cfg`` (built once)."""
    return section_of(cfg, "outputs", OutputSettings)


__all__ = ["MetricsSettings", "ModbusOutputSettings", "OpcUaSettings", "OutputSettings",
           "WebSettings",
           "output_settings"]
