"""Plain JSON from analysis results and message bodies: the one converter the bus, the MCAP
writer and the report writers share."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def finite_or_none(v: float) -> float | None:
    """A number as JSON carries it: a finite float, or ``None`` for NaN and infinities (the
    rule of :func:`jsonable`, for one value)."""
    v = float(v)
    return v if math.isfinite(v) else None


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars made Python numbers, arrays and tuples made lists, keys made
    strings, and non-finite floats made ``None`` (JSON has no NaN, and every MCAP and Zenoh
    reader must parse what we write)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [jsonable(v) for v in x.tolist()]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return finite_or_none(x)
    return x


def dumps(x: Any, indent: int | None = None) -> str:
    """``x`` as strict JSON text (:func:`jsonable` first; compact unless ``indent``)."""
    separators = (",", ":") if indent is None else None
    return json.dumps(jsonable(x), allow_nan=False, indent=indent, separators=separators)
