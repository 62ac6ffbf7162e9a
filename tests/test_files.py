"""Files a person meets (``softsensor/files.py``): written whole with the user's umask, an
existing file keeping its mode (issue 24, item 7)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from softsensor.files import atomic_path


def _mode(path: Path) -> int:
    return path.stat().st_mode & 0o777


@pytest.fixture
def umask():
    """Set the process umask for one test, restored after."""
    old = os.umask(0o022)
    os.umask(old)
    yield os.umask
    os.umask(old)


def test_files_replaced_whole_get_the_users_umask(tmp_path, umask):
    from softsensor.calibration.params_file import write_params
    from softsensor.presentation.calibration_figures import write_page

    umask(0o022)
    params = write_params(tmp_path / "params.toml", {"fit": {"cost": 0.1}})
    page = write_page(tmp_path, "Report", [("A", "text")])
    assert _mode(params) == 0o644 and _mode(page) == 0o644
    umask(0o077)
    with atomic_path(tmp_path / "private.txt") as tmp:
        tmp.write_text("x")
    assert _mode(tmp_path / "private.txt") == 0o600
    os.chmod(params, 0o640)  # a file that exists keeps its mode, as open(..., "w") would
    write_params(params, {"fit": {"cost": 0.2}})
    assert _mode(params) == 0o640 and "0.2" in params.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index.html", "params.toml",
                                                          "private.txt"]
