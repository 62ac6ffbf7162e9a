"""Numba's on-disk cache, keyed by every source the compiled kernels inline.

``@njit(cache=True)`` checks only the modification time of the file that defines the compiled
function. The model's kernels inline the property functions of other modules
(``numba.extending.register_jitable``: cell physics, cell solver, march, humid air, wood,
transfer coefficients) and freeze the module globals they read as constants (the positions of
the inputs and parameters, from the name tuples of ``signals.py`` and ``plantconfig.py``), so
an edit there, or an upgrade that changes only those files, would silently reuse kernels
compiled from the old physics or the old order. :func:`configure` points numba's cache at a
folder named by a hash of all sources of the compiled packages and of those modules, so a
change to any of them compiles afresh (``tests/test_jit_cache.py`` checks that every module a
compiled module imports is hashed). A user's own
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
#: Modules outside them whose values the kernels freeze at compile time: the orders of
#: ``INPUT_NAMES`` and ``PARAMETER_NAMES`` give the kernels' input and parameter indices.
COMPILED_MODULES: tuple[str, ...] = ("signals.py", "plantconfig.py")

_configured = False


def compiled_sources(root: Path | None = None) -> list[Path]:
    """Every ``.py`` file of :data:`COMPILED_PACKAGES`, then :data:`COMPILED_MODULES`, in a
    fixed order."""
    root = Path(__file__).parent if root is None else root
    files = [p for pkg in COMPILED_PACKAGES for p in sorted((root / pkg).glob("*.py"))]
    return files + [root / m for m in COMPILED_MODULES]


def sources_digest(root: Path | None = None) -> str:
    """Short SHA-256 of :func:`compiled_sources` (paths and contents)."""
    root = Path(__file__).parent if root is None else root
    h = hashlib.sha256()
    for p in compiled_sources(root):
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
