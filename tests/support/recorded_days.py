"""Recorded days for the recording tests: scans of every signal at a 10 s period, a few lab
results, health and ground truth, written by the real :class:`DayWriter`."""

from __future__ import annotations

from pathlib import Path

from softsensor.recording.day_writer import DayWriter
from softsensor.signals import SCAN_SIGNALS, TOPIC_HEALTH, TOPIC_LAB, TOPIC_SCAN

T0 = 1_750_000_000 * 10**9  # 2025-06-15, ns since epoch
PERIOD = 10 * 10**9


def scan(i: int) -> dict:
    body = {name: 300.0 + k + 0.01 * i for k, name in enumerate(SCAN_SIGNALS)}
    body["time_ns"] = T0 + i * PERIOD
    return body


def write_day(path: Path, n: int = 600, chunk_size: int = 4096) -> None:
    with DayWriter(path, chunk_size=chunk_size) as w:
        for i in range(n):
            w.write(TOPIC_SCAN, T0 + i * PERIOD, scan(i))
            if i % 200 == 100:
                w.write(TOPIC_LAB, T0 + i * PERIOD + 1,
                        {"sample_time_ns": T0 + (i - 180) * PERIOD, "moisture_out": 0.1 + i / 1e4,
                         "sample_id": f"L{i}"})
            if i % 60 == 0:
                w.write(TOPIC_HEALTH, T0 + i * PERIOD, {"status": "ok", "detail": "fine"})
        w.write("/truth/plant", T0, {"moisture_in": 1.0, "note": "x", "T_wall": None})
        w.write("/truth/plant", T0 + 600 * 10**9, {"moisture_in": 1.1})


__all__ = ["PERIOD", "T0", "scan", "write_day"]
