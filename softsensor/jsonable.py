"""Turning results and message bodies into plain JSON: the one converter the report writers and
the MCAP recorder share."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars and arrays made Python numbers and lists, tuples made lists,
    keys made strings, and non-finite floats made ``None`` (JSON has no NaN).

    The result passes ``json.dumps(..., allow_nan=False)``.
    """
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return [jsonable(v) for v in x.tolist()]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x
