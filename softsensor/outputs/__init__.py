"""Estimates where operators and plant systems look: servers the daemon runs beside the bus.

Each output is off unless its ``[outputs.<name>]`` table says ``enabled = true``
(:mod:`.settings`), listens on loopback unless told otherwise, and only serves what the
estimator published; none of them writes to the PLC. Each is an
:class:`~.operator_output.OperatorOutput`, built by :func:`~.operator_output.operator_outputs`:
:mod:`.modbus_server`, the latest estimate as Modbus input registers for a DCS to poll;
:mod:`.metrics`, Prometheus metrics; :mod:`.opcua_server`, OPC UA variables with their
history; :mod:`.web`, the live page (its charts in :mod:`.web_charts`, its HTTP server in
:mod:`.deadline_http`).
"""
