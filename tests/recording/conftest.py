"""The recorded day the recording tests write and read (:mod:`recorded_days`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from recorded_days import write_day


@pytest.fixture
def day(tmp_path: Path) -> Path:
    """A 100-minute day of every topic, written in small chunks."""
    path = tmp_path / "day.mcap"
    write_day(path)
    return path
