"""Estimates of a recording as one table for historians and spreadsheets.

One row per ``/softsensor/estimate`` message (CONTRACT section 2) of a replay or daemon
recording: ``time_utc`` (ISO-8601, UTC), ``time_ns`` (its log time), then every numeric field
of the estimate body in SI units (booleans such as ``lab_updated`` as 0/1; a field that is
``null`` in a message is empty), then the health in force at that time, joined by log time (the
last ``/softsensor/health`` message at or before the estimate): ``health_status`` and every
numeric health field, prefixed ``health_``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import pandas as pd

from softsensor.errors import IngestError
from softsensor.messages import is_number
from softsensor.recording.mcap_day import iter_messages
from softsensor.signals import TOPIC_ESTIMATE, TOPIC_HEALTH


def _numeric_columns(bodies: list[dict[str, Any]]) -> dict[str, pd.Series]:
    """Every field that is a number or a boolean in some body, in order of first appearance.

    A field whose values are all integers or booleans (counts, ns times, flags) becomes a
    nullable integer column, so a ns time keeps all its digits; any other becomes float.
    """
    names: dict[str, bool] = {}  # name -> all values integral
    for body in bodies:
        for key, v in body.items():
            if isinstance(v, bool) or is_number(v):
                names[key] = names.get(key, True) and not isinstance(v, float)
    cols: dict[str, pd.Series] = {}
    for key, integral in names.items():
        vals = [body.get(key) for body in bodies]
        vals = [int(v) if isinstance(v, bool) else v if is_number(v) else None for v in vals]
        cols[key] = pd.Series(vals, dtype="Int64" if integral else "float64")
    return cols


def estimates_table(path: str | os.PathLike[str]) -> pd.DataFrame:
    """The estimates of the recording ``path`` as a DataFrame (see the module doc)."""
    est_t: list[int] = []
    est: list[dict[str, Any]] = []
    health_t: list[int] = []
    health: list[dict[str, Any]] = []
    for topic, t, body in iter_messages(path, topics=[TOPIC_ESTIMATE, TOPIC_HEALTH]):
        if topic == TOPIC_ESTIMATE:
            est_t.append(t)
            est.append(body)
        else:
            health_t.append(t)
            health.append(body)
    if not est:
        raise IngestError(f"{path}: no {TOPIC_ESTIMATE} messages (is it a replay or daemon "
                          "recording?)")
    times = np.asarray(est_t, dtype=np.int64)
    table: dict[str, Any] = {
        "time_utc": pd.to_datetime(times, unit="ns", utc=True).strftime(
            "%Y-%m-%dT%H:%M:%S.%fZ").str.replace(".000000Z", "Z", regex=False),
        "time_ns": times,
    }
    table.update(_numeric_columns(est))
    if health:
        # Health at or before each estimate: messages logged at the same time come after the
        # estimate they describe, so the last one with log time <= the estimate's wins.
        h_times = np.asarray(health_t, dtype=np.int64)
        pick = np.searchsorted(h_times, times, side="right") - 1
        have = pick >= 0
        status = np.array([health[j].get("status") if ok else None
                           for j, ok in zip(pick, have, strict=True)], dtype=object)
        table["health_status"] = status
        for key, col in _numeric_columns(health).items():
            picked = col.iloc[np.maximum(pick, 0)].reset_index(drop=True)
            table[f"health_{key}"] = picked.where(pd.Series(have), None)
    return pd.DataFrame(table)
