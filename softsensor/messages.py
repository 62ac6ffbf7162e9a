"""What flows on the bus and in recorded days, as the core sees it: pure types and parsing.

Both sides import this module: the adapters (:mod:`softsensor.recording`, :mod:`softsensor.bus`,
:mod:`softsensor.ingest`) turn bytes into these objects, the core (:mod:`softsensor.estimation`,
:mod:`softsensor.calibration`, :mod:`softsensor.diagnosis`) works on them. No I/O here.

* :func:`scan_values`: a ``/plant/scan`` body (CONTRACT section 2) to SI floats per signal;
* :class:`Window`: the scans of one model window, averaged (the estimator's and the
  calibration's unit of data, built by :mod:`softsensor.windows.accumulator`);
* :class:`LabResult`: one laboratory moisture result with its sample and log times, valid by
  construction: the one lab-result contract (:func:`moisture_problem`,
  :func:`sample_time_problem`, :func:`sample_id_problem`) is checked when one is made, so
  whoever holds one (the service's queue, the estimator, calibration) need not check again;
* :func:`encode_body`: a body as the JSON bytes sent on the bus and written to MCAP (one
  encoding for both, so a recorded day replays byte for byte).
* :func:`lab_from_body`: a ``/plant/lab`` body (live from the bus, a dropped lab file or a
  recorded day) to a :class:`LabResult`, or :class:`IngestError` with the one-line reason it
  is refused (a missing or non-finite moisture is refused, never turned into NaN).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta, tzinfo
from typing import Any

from softsensor.errors import IngestError, one_line
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
        taken inside the window saw (:mod:`softsensor.windows.lab_alignment`).
    refused : dict[str, int]
        Values per signal refused as implausible before they were averaged
        (:mod:`softsensor.windows.plausibility`); the reason is in ``reasons``.
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
    refused: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class LabResult:
    """A laboratory moisture result. ``moisture_out`` in kg/kg dry basis; times in ns since
    the Unix epoch (UTC): when the fibre was sampled and when the result was logged (arrived;
    None: not known).

    Valid by construction: one that breaks the lab-result contract (a moisture outside
    :data:`MOISTURE_RANGE` or 0, a sample time before 2000 or after the result arrived, an
    empty or overlong ``sample_id``) raises :class:`IngestError` with the reason.
    """

    sample_time_ns: int
    moisture_out: float
    sample_id: str
    log_time_ns: int | None = None

    def __post_init__(self) -> None:
        problem = lab_problem(self.sample_time_ns, self.moisture_out, self.sample_id,
                              self.log_time_ns)
        if problem is not None:
            raise IngestError(problem)

    @property
    def due_ns(self) -> int:
        """When the result may be applied [ns]: once it has arrived (its log time), and never
        before its sample time (the sample time alone when the arrival is not known). The one
        queue of pending results, the estimator service's, hands a result over at the tick of
        the window that holds this time."""
        if self.log_time_ns is None:
            return int(self.sample_time_ns)
        return max(int(self.log_time_ns), int(self.sample_time_ns))


def encode_body(body: dict[str, Any]) -> bytes:
    """Encode a message body as compact JSON bytes (:func:`softsensor.jsonable.dumps`:
    non-finite floats become ``null``, numpy values Python ones)."""
    return dumps(body).encode()


#: Plausible range of a lab moisture result [kg/kg dry basis], 0 itself refused: the one range
#: every lab result is held to, on the bus, from the lab folder, from a LIMS import, in a
#: recorded day and in the estimator (whose statistical gate judges a plausible value against
#: its estimate). Above 2 kg/kg (67 % on a wet basis) is no fibre out of a dryer: most likely a
#: % read as kg/kg, which the lab folder's and the import's messages name the key for.
MOISTURE_RANGE: tuple[float, float] = (0.0, 2.0)
#: Sample times before this are refused (likely seconds or ms given as ns) [ns since epoch].
EARLIEST_SAMPLE_NS = 946_684_800 * 10**9  # 2000-01-01T00:00:00Z
#: How far a sample time may lie after its result arrived [ns]: not at all. A result comes
#: tens of minutes after its sample; one stamped later than its own arrival has a clock or a
#: time zone wrong (an hour of summer time), and applied it would correct the wrong window.
#: With none, a result handed on when it has arrived always finds its window ticked or
#: ticking, so the service's queue is the only place results wait.
SAMPLE_AFTER_ARRIVAL_NS = 0
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)

def iso_utc(ns: int) -> str:
    """``2026-01-05T00:00:00Z`` for a time in ns since the Unix epoch (messages' times in the
    words a person reads)."""
    return (_EPOCH + timedelta(microseconds=int(ns) // 1000)).strftime("%Y-%m-%dT%H:%M:%SZ")


# ----------------------------------------------------------------------------------------------
# Lab bodies: one parser for the live and the recorded path


def parse_sample_time(value: Any, where: str = "lab", zone: tzinfo | None = None) -> int:
    """A sample time [ns since epoch, UTC] from ns (int or digits) or ISO-8601; an ISO time
    without an offset is on the clock of ``zone`` (a lab writes the plant's local time; the
    daemon passes its ``[display]`` time zone), UTC when None."""
    if isinstance(value, bool) or value is None:
        raise IngestError(f"{where}: sample_time {value!r} is not a time")
    if isinstance(value, float):
        if not value.is_integer():
            raise IngestError(f"{where}: sample_time {value!r} is not an integer of ns")
        value = int(value)
    if isinstance(value, int):
        return value
    if not isinstance(value, str):
        raise IngestError(f"{where}: sample_time {value!r} is not a time")
    text = value.strip()
    if text.lstrip("-").isdigit():
        return int(text)
    try:
        dt = datetime.fromisoformat(text)
    except ValueError as exc:
        raise IngestError(
            f"{where}: sample_time {text!r} is neither ISO-8601 nor ns since the epoch") from exc
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=zone or UTC)
    delta = dt - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * 10**9 + delta.microseconds * 1000


def _moisture(value: Any, where: str) -> float:
    """A moisture cell or field as a float (the contract is checked by :class:`LabResult`)."""
    if isinstance(value, bool) or value is None:
        raise IngestError(f"{where}: moisture_out {value!r} is not a number")
    if isinstance(value, str):
        try:
            value = float(value.strip())
        except ValueError as exc:
            raise IngestError(f"{where}: moisture_out {value!r} is not a number") from exc
    if not isinstance(value, (int, float)):
        raise IngestError(f"{where}: moisture_out {value!r} is not a number")
    return float(value)


# ----------------------------------------------------------------------------------------------
# The lab-result contract: each rule once. A rule's text names no value (the lab folder quotes
# nothing of a file it refuses); lab_problem, for the bus and recorded days, adds them.


def moisture_problem(x: float) -> str | None:
    """Why ``x`` [kg/kg dry basis] cannot be a lab result's moisture (None when it can)."""
    if not math.isfinite(x):
        return "is not finite"
    lo, hi = MOISTURE_RANGE
    if x == lo:  # a bone-dry sample out of a dryer is a LIMS default or a typing slip
        return "is 0: a bone-dry sample is a LIMS default or a typing slip, not a measurement"
    if not lo < x <= hi:
        return f"is outside the plausible range {lo:g}..{hi:g} kg/kg dry basis"
    return None


def sample_time_problem(sample_time_ns: int, log_time_ns: int | None) -> str | None:
    """Why a sample time [ns] cannot be that of a result that arrived at ``log_time_ns`` [ns]
    (None when it can; :data:`SAMPLE_AFTER_ARRIVAL_NS`)."""
    if sample_time_ns < EARLIEST_SAMPLE_NS:
        return "is before 2000 (seconds or ms given instead of ns?)"
    if log_time_ns is not None and sample_time_ns > log_time_ns + SAMPLE_AFTER_ARRIVAL_NS:
        ahead = (sample_time_ns - log_time_ns) / 60e9
        return f"lies {ahead:.1f} min after the result arrived"
    return None


#: Longest lab sample id [characters]: a LIMS id is short; a 60 kB one is an attack on every
#: log line, health answer and checkpoint it would reach.
MAX_SAMPLE_ID_CHARS = 128


def sample_id_problem(sample_id: str) -> str | None:
    """Why ``sample_id`` cannot name a lab result (None when it can)."""
    if not isinstance(sample_id, str):
        return f"is a {type(sample_id).__name__}, not text"
    if not sample_id.strip():
        return "is empty"
    if len(sample_id) > MAX_SAMPLE_ID_CHARS:
        return f"of {len(sample_id)} characters is longer than {MAX_SAMPLE_ID_CHARS}"
    return None


def lab_problem(sample_time_ns: int, moisture_out: float, sample_id: str,
                log_time_ns: int | None) -> str | None:
    """Why these fields cannot make a :class:`LabResult` (None when they can): the contract,
    one line naming the field and, for the moisture and the time, the value."""
    problem = sample_id_problem(sample_id)
    if problem is not None:
        return f"sample_id {problem}"
    problem = sample_time_problem(sample_time_ns, log_time_ns)
    if problem is not None:
        return f"lab {sample_id!r}: sample_time {sample_time_ns} ns {problem}"
    problem = moisture_problem(moisture_out)
    if problem is not None:
        return f"lab {sample_id!r}: moisture_out {moisture_out:g} kg/kg {problem}"
    return None


def _sample_id(value: Any, where: str) -> str:
    """A sample id field as text (the contract is checked by :class:`LabResult`)."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise IngestError(f"{where}: sample_id {one_line(repr(value), 60)} is not a string")
    return str(value).strip()


def make_lab_result(sample_time: Any, moisture_out: Any, sample_id: Any, *,
                    log_time_ns: int | None = None, where: str = "lab",
                    zone: tzinfo | None = None) -> LabResult:
    """Parse one entry into a :class:`LabResult` (which checks the contract);
    :class:`IngestError` naming ``where`` with the reason.

    ``log_time_ns`` is when the result became available [ns since epoch].
    """
    st = parse_sample_time(sample_time, where, zone)
    moisture, sid = _moisture(moisture_out, where), _sample_id(sample_id, where)
    try:
        return LabResult(sample_time_ns=st, moisture_out=moisture, sample_id=sid,
                         log_time_ns=log_time_ns)
    except IngestError as exc:
        raise IngestError(f"{where}: {one_line(str(exc), 300)}") from None


def lab_from_body(body: dict[str, Any], log_time_ns: int | None = None,
                  where: str = "lab", zone: tzinfo | None = None) -> LabResult:
    """A :class:`LabResult` from a JSON object (bus body or file entry).

    The sample time is ``sample_time_ns`` or ``sample_time``; ``log_time_ns`` defaults to the
    body's ``time_ns`` when present.
    """
    if not isinstance(body, dict):
        raise IngestError(f"{where}: lab entry is a JSON {type(body).__name__}, not an object")
    missing = [k for k in ("moisture_out", "sample_id") if k not in body]
    if "sample_time_ns" not in body and "sample_time" not in body:
        missing.insert(0, "sample_time_ns")
    if missing:
        raise IngestError(f"{where}: lab entry lacks {', '.join(missing)}")
    st = body["sample_time_ns"] if "sample_time_ns" in body else body["sample_time"]
    if log_time_ns is None and isinstance(body.get("time_ns"), int):
        log_time_ns = body["time_ns"]
    return make_lab_result(st, body["moisture_out"], body["sample_id"],
                           log_time_ns=log_time_ns, where=where, zone=zone)


def lab_body(lab: LabResult) -> dict[str, Any]:
    """The ``/plant/lab`` body (CONTRACT section 2) of a lab result."""
    return {"sample_time_ns": lab.sample_time_ns, "moisture_out": lab.moisture_out,
            "sample_id": lab.sample_id}



__all__ = [
    "EARLIEST_SAMPLE_NS",
    "MOISTURE_RANGE",
    "SAMPLE_AFTER_ARRIVAL_NS",
    "SCAN_EXTRA_FIELDS",
    "LabResult",
    "Window",
    "encode_body",
    "is_number",
    "iso_utc",
    "lab_body",
    "lab_from_body",
    "lab_problem",
    "make_lab_result",
    "moisture_problem",
    "parse_sample_time",
    "sample_id_problem",
    "sample_time_problem",
    "scan_values",
]
