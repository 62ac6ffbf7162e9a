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

from softsensor.errors import ConfigError

#: The name of standard output where a verb takes a file.
STDOUT = "-"


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


def check_target(target: str | os.PathLike[str] | None, flag: str = "--json") -> None:
    """Refuse, before the work, an output file that cannot be written: a folder, a missing
    or read-only folder. ``-`` (stdout) and None pass."""
    if target is None or str(target) == STDOUT:
        return
    p = Path(target)
    if p.is_dir():
        raise ConfigError(f"{flag} {p}: is a directory, not a file")
    parent = p.resolve().parent
    if not parent.is_dir():
        raise ConfigError(f"{flag} {p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ConfigError(f"{flag} {p}: directory {parent} is not writable")


@contextlib.contextmanager
def writing(target: str | os.PathLike[str], flag: str = "--out") -> Iterator[Path]:
    """A temporary path to write ``target`` through (:func:`softsensor.files.atomic_path`),
    after checking, before any work, that ``target`` can be written (:func:`check_target`).
    Every verb's output file goes through here."""
    check_target(target, flag)
    with atomic_path(target) as tmp:
        yield tmp


def replace_file(target: str | os.PathLike[str], data: bytes, flag: str = "--out") -> Path:
    """Write ``data`` beside ``target`` and rename it over ``target`` (:func:`writing`)."""
    with writing(target, flag) as tmp:
        tmp.write_bytes(data)
    return Path(target)


__all__ = ["STDOUT", "atomic_path", "check_target", "replace_file", "writing"]
