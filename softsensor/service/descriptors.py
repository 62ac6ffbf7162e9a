"""The daemon's open file descriptors against the process limit, for its health.

Every socket a client holds is a descriptor; at the process limit (``ulimit -n``) the daemon
can no longer write its checkpoint, list the lab folder or accept a connection (issue 40:
2,000 idle Modbus clients near a 20,000 limit made checkpoints fail with ``Too many open
files`` while health said ``ok``). The servers now bound their connections; this watch is the
last line: health says ``degraded`` with the count once more than :data:`NEAR` of the limit
is open, and ``ok`` again below :data:`CLEAR` (a margin, so a count hovering at the line does
not flap); a count that fails is said too, and a descriptor is kept in reserve for it
(:class:`DescriptorWatch`).
"""

from __future__ import annotations

import contextlib
import os
import resource
from collections.abc import Callable

#: Fraction of the limit from which health says so.
NEAR = 0.80
#: Fraction of the limit below which it stops saying so.
CLEAR = 0.70
_FD_DIR = "/proc/self/fd"


class CountFailed(OSError):
    """The descriptors could not be counted although the system tells them (``/proc`` is
    there): at the limit, listing ``/proc/self/fd`` itself needs a descriptor."""


def open_descriptors() -> int | None:
    """Descriptors open in this process now; None where the system does not tell (no
    ``/proc``); :class:`CountFailed` when it does but the count failed."""
    try:
        return len(os.listdir(_FD_DIR))
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise CountFailed(exc.errno, os.strerror(exc.errno or 0)) from exc


def descriptor_limit() -> int | None:
    """The process' soft limit on open descriptors; None when unlimited."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


class DescriptorWatch:
    """Says when the open descriptors near the limit (module docstring); :meth:`check`
    returns the health's words (None: nothing to say).

    It holds one descriptor in reserve (``/dev/null``) for its own count: when every other
    one is taken, the count closes it, lists ``/proc/self/fd`` with the one freed and takes
    it back, so the watch still sees the limit it watches for (issue 49: the count failed
    there and health said ``ok`` for 55 s while checkpoints failed). A count that fails even
    so is itself the news: health says the descriptors could not be counted."""

    def __init__(self, count: Callable[[], int | None] = open_descriptors,
                 limit: Callable[[], int | None] = descriptor_limit) -> None:
        self._count, self._limit = count, limit
        self.said: str | None = None  #: the words of the last check (None: not near)
        self._reserve: int | None = None
        self._take_reserve()

    def _take_reserve(self) -> None:
        if self._reserve is None:
            try:
                self._reserve = os.open(os.devnull, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                self._reserve = None

    def close(self) -> None:
        """Give the reserve descriptor back (idempotent)."""
        fd, self._reserve = self._reserve, None
        if fd is not None:
            os.close(fd)

    def __del__(self) -> None:  # a watch dropped without close (a daemon never run)
        with contextlib.suppress(Exception):
            self.close()

    @property
    def near(self) -> bool:
        """Whether the last check found the descriptors near the limit."""
        return self.said is not None

    def _counted(self) -> int | None:
        """The count, with the reserve descriptor freed for it when it failed without."""
        try:
            return self._count()
        except CountFailed:
            if self._reserve is None:
                raise
        os.close(self._reserve)
        self._reserve = None
        try:
            return self._count()
        finally:
            self._take_reserve()

    def check(self) -> str | None:
        """Count now; the words for health while near the limit, else None."""
        limit = self._limit()
        try:
            n = self._counted()
        except CountFailed as exc:
            self.said = (f"{exc.strerror} while counting the open file descriptors (limit "
                         f"{limit}): at the process limit, at which checkpoints, the lab "
                         f"folder and new connections fail")
            return self.said
        if n is None or not limit:
            self.said = None
            return None
        share = n / limit
        near = share >= NEAR or (self.near and share >= CLEAR)
        self.said = (f"{n} of {limit} file descriptors open ({100 * share:.0f} %): near the "
                     f"process limit, at which checkpoints, the lab folder and new "
                     f"connections fail") if near else None
        return self.said


__all__ = ["CLEAR", "NEAR", "CountFailed", "DescriptorWatch", "descriptor_limit",
           "open_descriptors"]
