"""The daemon's open file descriptors against the process limit, for its health.

Every socket a client holds is a descriptor; at the process limit (``ulimit -n``) the daemon
can no longer write its checkpoint, list the lab folder or accept a connection (issue 40:
2,000 idle Modbus clients near a 20,000 limit made checkpoints fail with ``Too many open
files`` while health said ``ok``). The servers now bound their connections; this watch is the
last line: health says ``degraded`` with the count once more than :data:`NEAR` of the limit
is open, and ``ok`` again below :data:`CLEAR` (a margin, so a count hovering at the line does
not flap).
"""

from __future__ import annotations

import os
import resource
from collections.abc import Callable

#: Fraction of the limit from which health says so.
NEAR = 0.80
#: Fraction of the limit below which it stops saying so.
CLEAR = 0.70
_FD_DIR = "/proc/self/fd"


def open_descriptors() -> int | None:
    """Descriptors open in this process now; None where the system does not tell
    (no ``/proc``)."""
    try:
        return len(os.listdir(_FD_DIR))
    except OSError:
        return None


def descriptor_limit() -> int | None:
    """The process' soft limit on open descriptors; None when unlimited."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


class DescriptorWatch:
    """Says when the open descriptors near the limit (module docstring); :meth:`check`
    returns the health's words (None: nothing to say)."""

    def __init__(self, count: Callable[[], int | None] = open_descriptors,
                 limit: Callable[[], int | None] = descriptor_limit) -> None:
        self._count, self._limit = count, limit
        self.said: str | None = None  #: the words of the last check (None: not near)

    @property
    def near(self) -> bool:
        """Whether the last check found the descriptors near the limit."""
        return self.said is not None

    def check(self) -> str | None:
        """Count now; the words for health while near the limit, else None."""
        n, limit = self._count(), self._limit()
        if n is None or not limit:
            self.said = None
            return None
        share = n / limit
        near = share >= NEAR or (self.near and share >= CLEAR)
        self.said = (f"{n} of {limit} file descriptors open ({100 * share:.0f} %): near the "
                     f"process limit, at which checkpoints, the lab folder and new "
                     f"connections fail") if near else None
        return self.said


__all__ = ["CLEAR", "NEAR", "DescriptorWatch", "descriptor_limit", "open_descriptors"]
