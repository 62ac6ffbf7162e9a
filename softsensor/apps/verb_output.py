"""How the verbs speak: one human line on stderr, JSON only where asked, files replaced whole.

Every verb ends with one line for a person on stderr (:func:`say`), so stdout stays free for
what a program asked for: JSON goes to the file named by ``--json``, or to stdout with
``--json -`` (:func:`write_json`), never both and never unasked. A file is written beside its
target and renamed over it (:func:`softsensor.files.replace_file`), so an interrupted run
leaves the previous file whole, and a target that cannot be written is refused before any work
starts (:func:`softsensor.files.check_target`).
"""

from __future__ import annotations

import os
import sys
from typing import Any

from softsensor.files import STDOUT, replace_file
from softsensor.jsonable import dumps


def say(verb: str, text: str) -> None:
    """The verb's one human line, on stderr."""
    print(f"{verb}: {text}", file=sys.stderr, flush=True)


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


__all__ = ["say", "write_json"]
