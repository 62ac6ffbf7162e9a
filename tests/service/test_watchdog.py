"""The daemon's watchdog before its first estimate (``softsensor/service/watchdog.py``).

Issue 49: on a normal start the daemon logged an ERROR ``estimator_stalled`` before its
first window: the wait was measured from the worker's creation, before the outputs and the
PLC connection were up (at a scaled clock, seconds of start-up are windows). Now nothing is
due before the first input, the first estimate is awaited from the first input with one
window more (the first window closes up to a window after it), and after it the rule is
the old one (``tests/faults/test_starvation.py``).
"""

from __future__ import annotations

import logging

from softsensor.service.watchdog import Watchdog


def test_no_stall_before_the_first_input_then_one_window_more_for_the_first_estimate(caplog):
    caplog.set_level(logging.INFO, logger="softsensor.service.watchdog")
    t: dict[str, float | None] = {"tick": 0.0, "first": None}
    w = Watchdog(600.0, 70.0, lambda: t["tick"], lambda: 0, lambda: t["first"])
    # no scan yet, however long: nothing is late (the input's health says "no scans")
    assert w.check(now=5000.0) is None and not w.stalled
    t["first"] = 5000.0
    # the first estimate: 2 windows + grace + one window from the first input
    assert w.check(now=5000.0 + 1869.0) is None and not w.stalled
    stall = w.check(now=5000.0 + 1871.0)
    assert stall is not None and stall.late_s == 1871.0 and w.stalled
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    # once an estimate went out, the old rule: 2 windows + grace from it
    t["tick"] = 7000.0
    assert w.check(now=7001.0) is None and not w.stalled
    assert w.check(now=7000.0 + 1269.0) is None
    assert w.check(now=7000.0 + 1271.0) is not None


def test_a_normal_start_logs_no_stall_error(caplog):
    """A start whose outputs and PLC connection take many windows of a scaled clock (1 s a
    window here), then scans and a first estimate within its window: no ERROR."""
    caplog.set_level(logging.INFO, logger="softsensor.service.watchdog")
    t: dict[str, float | None] = {"tick": 100.0, "first": None}
    w = Watchdog(1.0, 0.2, lambda: t["tick"], lambda: 0, lambda: t["first"])
    for now in (101.0, 105.0, 130.0):  # the outputs start, the PLC connects
        assert w.check(now=now) is None
    t["first"] = 130.0
    assert w.check(now=131.5) is None  # the first (partial) window closes, its tick is due
    t["tick"] = 131.6
    assert w.check(now=132.0) is None
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
