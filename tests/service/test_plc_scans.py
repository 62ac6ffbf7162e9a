"""The daemon's own PLC scans told apart from other senders' (``softsensor/service/
plc_scans.py``, issue 40), without a network."""

from __future__ import annotations

from softsensor.bus.transport import BusMessage
from softsensor.service.plc_scans import OTHER, PLC, REFUSED, PlcScans

S = 10**9


def _scan(t_s: int, **body) -> BusMessage:
    return BusMessage("scan", "plant/dryer1/scan", {**body, "time_ns": t_s * S}, t_s * S)


def test_own_scans_are_known_and_hold_off_other_senders_for_three_periods():
    now = [0]
    scans = PlcScans(lambda: now[0] * S, scan_period_s=10.0)
    assert scans.origin(_scan(1, T_air_in=480.0)) == OTHER  # no PLC scan yet: taken
    scans.sent(5 * S, {"T_air_in": 452.25, "quality": {"m_air": "stale"}})
    now[0] = 5
    assert scans.origin(_scan(5, T_air_in=452.25, quality={"m_air": "stale"})) == PLC
    assert scans.origin(_scan(5, T_air_in=452.25, quality={"m_air": "stale"})) == REFUSED
    assert scans.origin(_scan(6, T_air_in=480.0)) == REFUSED  # a copy with other values
    lab = BusMessage("lab", "plant/dryer1/lab", {"sample_id": "L1"}, 6 * S)
    assert scans.origin(lab) == OTHER  # lab results from anyone
    now[0] = 36  # more than three periods without the PLC: others are taken again
    assert scans.origin(_scan(36, T_air_in=480.0)) == OTHER
