"""The rate limit of repeated log lines (softsensor/log_throttle.py), on a fake clock."""

from __future__ import annotations

import logging

from softsensor.log_throttle import MAX_KINDS, TEXT_CHARS, Throttle, outside_text


def test_first_line_at_once_then_one_per_period_with_the_count(caplog):
    now = [0.0]
    t = Throttle(10.0, clock=lambda: now[0])
    log = logging.getLogger("test.throttle")
    caplog.set_level(logging.WARNING, "test.throttle")
    for i in range(100):
        now[0] = i * 0.25  # 25 s of a flood, four lines a second
        t.log(log, "bad", logging.WARNING, "bad message %d", i)
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0] == "bad message 0"
    assert lines[1] == "bad message 40 (39 more like it in the last 10 s not logged)"
    assert len(lines) == 3
    assert t.ready("other") == 0  # kinds are counted apart


def test_kinds_and_text_are_bounded():
    t = Throttle(10.0, clock=lambda: 0.0)
    for i in range(MAX_KINDS + 50):
        t.ready(f"kind {i}")
    assert len(t._last) <= MAX_KINDS + 1
    assert len(outside_text("k" * 60_000 + "\n")) == TEXT_CHARS
    assert "\n" not in outside_text("a\nb")
