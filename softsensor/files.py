"""Files replaced whole or not at all.

:func:`atomic_path` is the one way the project writes a file another program (or a later
run) reads: into a temporary file beside the target, renamed over it when complete. An
interrupted write (SIGTERM, a full disk, an exception) leaves the earlier file as it was and
no temporary behind. The file gets the mode a plain ``open(target, "w")`` would give it: the
target's own when it exists, else 0666 less the user's umask (``tempfile`` creates 0600, which
left reports and PARAMS.toml unreadable to the rest of a plant's team).
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path


def _umask() -> int:
    """The process's umask, read without changing it where Linux tells it (``os.umask`` can
    only be read by setting it, a race with other threads creating files)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _mode_for(target: Path) -> int:
    try:
        return stat.S_IMODE(os.stat(target).st_mode)
    except OSError:
        return 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """A new temporary path beside ``target`` (same suffix, hidden name) to write to; renamed
    over ``target`` (atomic on POSIX) when the block ends, removed when it raises."""
    p = Path(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=f".tmp{p.suffix}",
                               dir=p.resolve().parent)
    try:
        try:
            os.fchmod(fd, _mode_for(p))
        finally:
            os.close(fd)
        yield Path(tmp)
        os.replace(tmp, p)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


__all__ = ["atomic_path"]
