"""What flows on the bus and in recorded days, as the core sees it: pure types and parsing.

Both sides import this module: the adapters (:mod:`softsensor.recording`, :mod:`softsensor.bus`,
:mod:`softsensor.ingest`) turn bytes into these objects, the core (:mod:`softsensor.estimation`,
:mod:`softsensor.calibration`, :mod:`softsensor.diagnosis`) works on them. No I/O here.

* :func:`scan_values`: a ``/plant/scan`` body (CONTRACT section 2) to SI floats per signal;
* :class:`Window`: the scans of one model window, averaged (the estimator's and the
  calibration's unit of data, built by :mod:`softsensor.estimation.windowing`);
* :class:`LabResult`: one laboratory moisture result with its sample and log times;
* :func:`encode_body`: a body as the JSON bytes sent on the bus and written to MCAP (one
  encoding for both, so a recorded day replays byte for byte).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from softsensor.errors import IngestError
from softsensor.jsonable import dumps
from softsensor.signals import SCAN_SIGNALS

#: Non-signal fields a scan body may carry besides the signals (a Zenoh ``time_ns``, a counter).
SCAN_EXTRA_FIELDS: frozenset[str] = frozenset({"time_ns", "seq", "sequence", "scan_id", "unit"})


def is_number(v: Any) -> bool:
    """A JSON number (int or float, not bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def scan_values(body: dict[str, Any], where: str = "scan") -> dict[str, float]:
    """Signal values of a ``/plant/scan`` body in SI units, NaN for ``null`` or missing.

    Raises :class:`IngestError` naming ``where`` and the signal for a numeric field that is not
    a known signal (non-signal fields: :data:`SCAN_EXTRA_FIELDS`, names ending in ``_ns``, and
    non-numeric metadata) or for a signal whose value is not a number or null.
    """
    if not isinstance(body, dict):
        raise IngestError(f"{where}: scan body is {type(body).__name__}, not an object")
    out = dict.fromkeys(SCAN_SIGNALS, math.nan)
    for key, value in body.items():
        if key in out:
            if value is None:
                continue
            if not is_number(value):
                raise IngestError(f"{where}: signal {key} has non-numeric value {value!r}")
            out[key] = float(value)
        elif key in SCAN_EXTRA_FIELDS or key.endswith("_ns"):
            continue
        elif value is None or is_number(value):
            raise IngestError(f"{where}: unknown signal {key!r} in /plant/scan")
    return out


@dataclass(frozen=True)
class Window:
    """Scans of one model window, averaged.

    Attributes
    ----------
    start_ns, end_ns : int
        Window bounds, nanoseconds since the Unix epoch (UTC); the window is (start, end].
    means : dict[str, float | None]
        Mean of the good (non-null) values of each scan signal; ``None`` when the signal had
        too few good values.
    n_scans : int
        Scans received in the window.
    n_good : dict[str, int]
        Good values per signal.
    stale : bool
        True when the window has too few good scans to be used for correction.
    reasons : dict[str, str]
        Why a signal was dropped (for the health message).
    bin_s : float
        Length of the sub-window bins [s] (0: no bins).
    bins : dict[str, list[float | None]]
        Per measured model input, the mean of its good values in each consecutive bin of
        ``bin_s`` seconds of the window (``None`` for a bin without one): what a lab sample
        taken inside the window saw (:mod:`softsensor.estimation.lab_alignment`).
    """

    start_ns: int
    end_ns: int
    means: dict[str, float | None]
    n_scans: int
    n_good: dict[str, int] = field(default_factory=dict)
    stale: bool = False
    reasons: dict[str, str] = field(default_factory=dict)
    bin_s: float = 0.0
    bins: dict[str, list[float | None]] = field(default_factory=dict)


@dataclass(frozen=True)
class LabResult:
    """A laboratory moisture result. ``moisture_out`` in kg/kg dry basis; times in ns since
    the Unix epoch (UTC): when the fibre was sampled and when the result was logged."""

    sample_time_ns: int
    moisture_out: float
    sample_id: str
    log_time_ns: int | None = None


def encode_body(body: dict[str, Any]) -> bytes:
    """Encode a message body as compact JSON bytes (:func:`softsensor.jsonable.dumps`:
    non-finite floats become ``null``, numpy values Python ones)."""
    return dumps(body).encode()


__all__ = ["SCAN_EXTRA_FIELDS", "LabResult", "Window", "encode_body", "is_number",
           "scan_values"]
