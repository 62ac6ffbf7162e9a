"""Numbers stored by one machine and compared on another, at a stated tolerance.

The model's outputs (``model_digest.py``) and the demo day's estimates
(``estimate_digest.py``) are pinned against reference numbers in ``tests/fixtures``. numba
compiles for the host CPU and the system's ``libm``, so the same code on another machine may
differ in the last bits (measured: 2.3e-14 relative on the demo day's last estimate, issue
49): a test that compared them bit for bit was red on every machine but the one that wrote
them. The reference is therefore the numbers themselves, and a number matches when

    ``|now - stored| <= RTOL * max(|stored|, FLOOR * scale) + ATOL``

with ``scale`` the largest magnitude of its field (an output array, an estimate's key) over
the reference: 1e-9 relative, 100,000 times the round-off seen between machines (1e-14)
and far below a change of the physics or the estimator that matters; a value near zero is
compared against 1e-5 of its field's size, and a field that is round-off itself (an exact
zero computed as 1e-18) against ATOL.
The SHA-256 of the raw bits is stored beside, and printed, as the bit-for-bit check on the
machine that wrote it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

#: Relative tolerance of a stored number (module docstring).
RTOL = 1e-9
#: Fraction of its field's largest magnitude below which a value is compared against that
#: (small enough that an array of temperatures [K] and moistures [kg/kg] compares both
#: relatively).
FLOOR = 1e-5
#: Absolute floor [SI units]: far below any measured or estimated quantity of a dryer.
ATOL = 1e-15
#: Significant digits stored: the rounding (5e-13 relative) is 2,000 times inside RTOL.
DIGITS = 12


def stored(value: float | int | None) -> float | int | None:
    """``value`` as the reference file keeps it: floats to :data:`DIGITS` digits."""
    if isinstance(value, float) and math.isfinite(value):
        return float(f"{value:.{DIGITS}g}")
    return value


def _scale(values: Sequence[float | int | None]) -> float:
    finite = [abs(float(v)) for v in values if v is not None and math.isfinite(float(v))]
    return max(finite, default=0.0)


def differences(now: Mapping[str, Sequence[float | int | None]],
                reference: Mapping[str, Sequence[float | int | None]], limit: int = 5
                ) -> list[str]:
    """What differs between two ``{field: values}`` beyond the tolerance, for a person
    (empty when they match): a field missing or of another length, an int or null that
    changed, a float outside the tolerance (the largest relative change per field)."""
    out: list[str] = []
    for field in sorted(set(now) | set(reference)):
        if field not in now or field not in reference:
            out.append(f"{field}: only in the {'reference' if field in reference else 'run'}")
            continue
        a, b = list(now[field]), list(reference[field])
        if len(a) != len(b):
            out.append(f"{field}: {len(a)} values, the reference {len(b)}")
            continue
        scale, worst = _scale(b), None
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            if not (isinstance(x, float) and isinstance(y, float)):  # ints, nulls: exact
                if x != y or type(x) is not type(y):
                    worst = worst or (i, x, y, math.inf)
                continue
            x, y = float(x), float(y)
            if not (math.isfinite(x) and math.isfinite(y)):
                if not (x == y or math.isnan(x) and math.isnan(y)):
                    worst = worst or (i, x, y, math.inf)
                continue
            err = abs(x - y)
            if err > RTOL * max(abs(y), FLOOR * scale) + ATOL:
                rel = err / max(abs(y), 1e-300)
                if worst is None or rel > worst[3]:
                    worst = (i, x, y, rel)
        if worst is not None:
            i, x, y, rel = worst
            out.append(f"{field}[{i}]: {x!r}, the reference {y!r} (relative change {rel:.3g})")
    return out[:limit] + ([f"... and {len(out) - limit} more"] if len(out) > limit else [])


__all__ = ["ATOL", "DIGITS", "FLOOR", "RTOL", "differences", "stored"]
