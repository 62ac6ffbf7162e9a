"""Every listed mutation of the physics and the estimator fails its tests
(``tests/support/mutation_check.py``; about 20 minutes on two cores, hence slow)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent / "mutation_check.py"


@pytest.mark.slow
def test_every_mutation_is_killed():
    r = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True,
                       timeout=3 * 3600)
    print(r.stdout)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "SURVIVED" not in r.stdout and "| killed |" in r.stdout


def test_every_mutation_snippet_is_in_the_code_once():
    """The list cannot go stale silently: each snippet names code that is there (a mutation
    whose original is gone would not be applied)."""
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        import mutation_check as mc
    finally:
        sys.path.pop(0)
    root = SCRIPT.parents[2]
    for m in mc.MUTATIONS:
        text = (root / m.file).read_text()
        assert text.count(m.original) == 1, (m.name, m.file)
        assert m.mutated != m.original and (root / m.selection[0]).is_file(), m.name
