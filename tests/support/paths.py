"""Where the tests find the repository's files, wherever a test module sits in ``tests/``."""

from __future__ import annotations

from pathlib import Path

#: The repository's root (``pyproject.toml``, ``replay/``, ``docs/``, ``config/``).
REPO = Path(__file__).resolve().parents[2]
#: The tests' own data files.
FIXTURES = REPO / "tests" / "fixtures"
#: The demo day, the historian and LIMS examples.
REPLAY = REPO / "replay"
#: The project's ``shared/`` folder beside the repository (the contract checker), when present.
SHARED = REPO.parent / "shared"
#: The contract's checker of a recorded day (``shared/tools/check_day.py``), when present.
CHECK_DAY = SHARED / "tools" / "check_day.py"

__all__ = ["CHECK_DAY", "FIXTURES", "REPLAY", "REPO", "SHARED"]
