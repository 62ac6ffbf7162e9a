"""The estimator interface: what the estimator service calls every 600 s tick.

A source (Modbus poller, MCAP replay, virtual plant) publishes scans; the service averages the
good scans of each window into a :class:`Window` and hands it to an :class:`Estimator`, which
returns the body of the ``/softsensor/estimate`` message (CONTRACT section 2). Lab results reach
the estimator through :meth:`Estimator.add_lab` whenever they arrive, possibly long after their
sample time. Estimators are pure: no I/O, no clocks; time is whatever the window says.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol


@dataclass(frozen=True)
class Window:
    """Scans of one estimator window, averaged.

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
    """

    start_ns: int
    end_ns: int
    means: dict[str, float | None]
    n_scans: int
    n_good: dict[str, int] = field(default_factory=dict)
    stale: bool = False
    reasons: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LabResult:
    """A laboratory moisture result. ``moisture_out`` in kg/kg dry basis."""

    sample_time_ns: int
    moisture_out: float
    sample_id: str
    log_time_ns: int | None = None


class Estimator(Protocol):
    """What the estimator service needs from an estimator."""

    def tick(self, window: Window) -> dict[str, Any]:
        """Advance to ``window.end_ns`` and return the estimate body.

        The body has at least ``moisture_out``, ``moisture_out_std``, ``moisture_in``,
        ``moisture_in_std``, ``T_dryer_out_model``, ``T_cyclone_out_model`` and ``lab_updated``.
        """
        ...

    def add_lab(self, lab: LabResult) -> str | None:
        """Queue a lab result; return ``None`` when accepted, else the reason it was refused."""
        ...

    def checkpoint(self) -> dict[str, Any]:
        """A JSON-serialisable snapshot from which :meth:`restore` resumes the same estimate."""
        ...

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Continue from a snapshot written by :meth:`checkpoint`."""
        ...
