"""How the verbs speak: one human line on stderr, JSON only where asked, files replaced whole.

Every verb ends with one line for a person on stderr (:func:`say`), so stdout stays free for
what a program asked for: JSON goes to the file named by ``--json``, or to stdout with
``--json -`` (:func:`write_json`), never both and never unasked. A file is written beside its
target and renamed over it (:func:`replace_file`), so an interrupted run leaves the previous
file whole, and a target that cannot be written is refused before any work starts
(:func:`check_target`).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from softsensor.errors import ConfigError
from softsensor.files import atomic_path
from softsensor.jsonable import dumps

STDOUT = "-"


def say(verb: str, text: str) -> None:
    """The verb's one human line, on stderr."""
    print(f"{verb}: {text}", file=sys.stderr, flush=True)


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


def write_json(doc: Any, target: str | os.PathLike[str] | None, flag: str = "--json") -> None:
    """``doc`` as indented JSON to ``target``: a file (replaced whole), ``-`` for stdout, or
    nowhere for None."""
    if target is None:
        return
    text = dumps(doc, indent=2) + "\n"
    if str(target) == STDOUT:
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    replace_file(target, text.encode("utf-8"), flag)


__all__ = ["STDOUT", "check_target", "replace_file", "say", "write_json", "writing"]
