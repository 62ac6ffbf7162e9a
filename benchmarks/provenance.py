"""What a benchmark result records of where it was measured: the commit and the machine.

A result in ``benchmarks/results/`` is quoted by the documentation with the commit and machine
that gave it; each benchmark script writes these fields from here, so they are read off the
checkout and the machine when it runs, not copied by hand afterwards.
"""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path


def commit() -> str | None:
    """The checkout's commit (with ``+`` when it has changes), for dating the result."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=here, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+" if dirty else "")


def machine() -> dict[str, object]:
    """The machine: its CPU count, processor, Python, and the load when this was called."""
    return {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "load_average": [round(x, 2) for x in os.getloadavg()]}


__all__ = ["commit", "machine"]
