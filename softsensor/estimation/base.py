"""The estimator interface: what the estimator service calls every 600 s tick.

A source (Modbus poller, MCAP replay, virtual plant) publishes scans; the service averages the
good scans of each window into a :class:`Window` and hands it to an :class:`Estimator`, which
returns the body of the ``/softsensor/estimate`` message (CONTRACT section 2). Lab results reach
the estimator through :meth:`Estimator.add_lab` whenever they arrive, possibly long after their
sample time. Estimators are pure: no I/O, no clocks; time is whatever the window says.
"""

from __future__ import annotations

from typing import Any, Protocol

from softsensor.messages import LabResult, Window

__all__ = ["Estimator", "LabResult", "Window"]


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
