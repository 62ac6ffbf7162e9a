"""Files replaced whole or not at all.

:func:`atomic_path` is the one way the project writes a file another program (or a later
run) reads: into a temporary file beside the target, renamed over it when complete. An
interrupted write (SIGTERM, a full disk, an exception) leaves the earlier file as it was and
no temporary behind.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """A new temporary path beside ``target`` (same suffix, hidden name) to write to; renamed
    over ``target`` (atomic on POSIX) when the block ends, removed when it raises."""
    p = Path(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=f".tmp{p.suffix}",
                               dir=p.resolve().parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


__all__ = ["atomic_path"]
