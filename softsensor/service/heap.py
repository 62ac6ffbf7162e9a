"""The daemon's heap: fewer malloc arenas, and freed memory given back to the system.

glibc's malloc gives each thread that meets contention an arena of its own (up to eight per
core) and keeps what was freed in them for reuse: after a flood of 60 kB messages decoded on
Zenoh's threads the daemon stayed 200 MB above its baseline for good (issue 31 item 2).
:func:`limit_arenas` caps the arenas at two before the daemon starts its threads (as
``MALLOC_ARENA_MAX=2`` would; a value in the environment wins), and :func:`trim` hands free
pages back (``malloc_trim(0)``), which the daemon's housekeeping calls every
:data:`TRIM_EVERY_S`. On a C library other than glibc both do nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import os

#: glibc's ``mallopt`` parameter for the number of arenas (malloc.h).
M_ARENA_MAX = -8
#: Arenas of the daemon: the main one and one for all other threads.
ARENAS = 2
#: Wall seconds between two :func:`trim` calls of the daemon's housekeeping.
TRIM_EVERY_S = 10.0


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        return libc if libc is not None and hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


def limit_arenas(arenas: int = ARENAS) -> bool:
    """Cap malloc's arenas at ``arenas`` unless ``MALLOC_ARENA_MAX`` is set; whether set."""
    libc = _libc()
    if libc is None or "MALLOC_ARENA_MAX" in os.environ:
        return False
    return bool(libc.mallopt(M_ARENA_MAX, int(arenas)))


def trim() -> bool:
    """Give the heap's free pages back to the system; whether any were."""
    libc = _libc()
    return bool(libc.malloc_trim(0)) if libc is not None else False


__all__ = ["ARENAS", "TRIM_EVERY_S", "limit_arenas", "trim"]
