"""Estimates where operators and plant systems look: servers the daemon runs beside the bus.

Each output is off unless its ``[outputs.<name>]`` table says ``enabled = true``
(:mod:`.settings`), listens on loopback unless told otherwise, and only serves what the
estimator published; none of them writes to the PLC. :mod:`.modbus_server`: the latest
estimate as Modbus input registers for a DCS to poll; :mod:`.metrics`: Prometheus metrics.
"""
