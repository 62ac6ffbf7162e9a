"""Numba's on-disk cache, keyed by every source the compiled kernels inline.

``@njit(cache=True)`` checks only the modification time of the file that defines the compiled
function. The model's kernels inline the property functions of other modules
(``numba.extending.register_jitable``: humid air, wood, transfer coefficients), so an edit
there, or an upgrade that changes only those files, would silently reuse kernels compiled from
the old physics. :func:`configure` points numba's cache at a folder named by a hash of all
sources of the compiled packages, so a change to any of them compiles afresh. A user's own
``NUMBA_CACHE_DIR`` is left alone; where the folder cannot be written, numba falls back to its
default locations by itself. Folders of other digests (older sources) untouched for a day
are removed.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import time
from pathlib import Path

#: Cache folders of other source digests older than this are removed [s].
STALE_AFTER = 86400.0
#: Packages whose modules are compiled together (relative to the softsensor package).
COMPILED_PACKAGES: tuple[str, ...] = ("model", "plant/independent")

_configured = False


def sources_digest(root: Path | None = None) -> str:
    """Short SHA-256 of every ``.py`` file of :data:`COMPILED_PACKAGES`, in a fixed order."""
    root = Path(__file__).parent if root is None else root
    h = hashlib.sha256()
    for pkg in COMPILED_PACKAGES:
        for p in sorted((root / pkg).glob("*.py")):
            h.update(p.relative_to(root).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def configure() -> None:
    """Set ``numba.config.CACHE_DIR`` before any cached kernel is defined (idempotent)."""
    global _configured
    if _configured or os.environ.get("NUMBA_CACHE_DIR"):
        return
    import numba

    here = Path(__file__).parent
    folder = here / "__pycache__" / f"numba-{sources_digest(here)}"
    now = time.time()
    for old in folder.parent.glob("numba-*"):
        with contextlib.suppress(OSError):
            if old != folder and now - old.stat().st_mtime > STALE_AFTER:
                shutil.rmtree(old)
    numba.config.CACHE_DIR = str(folder)
    _configured = True
