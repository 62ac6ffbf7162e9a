"""The package's layers hold, and a tool says so (import-linter, contracts in pyproject.toml).

The second test is the demonstration kept as a test: the same check on a copy of the package
in which the estimator imports the MCAP reader must fail, naming the import.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from paths import REPO

WINDOWING = Path("softsensor") / "windows" / "accumulator.py"
LINT = "from importlinter.cli import lint_imports_command; lint_imports_command()"


def _lint_imports(root: Path) -> subprocess.CompletedProcess[str]:
    """``lint-imports`` on the package under ``root`` (that copy first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run([sys.executable, "-c", LINT, "--no-cache",
                           "--config", str(root / "pyproject.toml")],
                          cwd=root, env=env, capture_output=True, text=True, timeout=120)


def _copy_package(dest: Path) -> Path:
    shutil.copytree(REPO / "softsensor", dest / "softsensor",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / "pyproject.toml", dest / "pyproject.toml")
    return dest


def test_the_package_keeps_its_layers() -> None:
    res = _lint_imports(REPO)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "Contracts: 3 kept, 0 broken." in res.stdout


def test_the_estimator_importing_the_mcap_reader_breaks_the_layers(tmp_path: Path) -> None:
    root = _copy_package(tmp_path)
    with open(root / WINDOWING, "a", encoding="utf-8") as f:
        f.write("\nimport softsensor.recording.mcap_day  # noqa: E402,F401\n")
    res = _lint_imports(root)
    assert res.returncode != 0
    assert "softsensor.windows.accumulator -> softsensor.recording.mcap_day" in res.stdout
    assert "BROKEN" in res.stdout
