"""Files a person meets (``softsensor/files.py``): written whole with the user's umask, an
existing file keeping its mode (issue 24, item 7)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from softsensor.errors import ConfigError
from softsensor.files import atomic_path, check_target, replace_file, writing


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


def test_targets_refused_before_the_work(tmp_path):
    with pytest.raises(ConfigError, match="is a directory"):
        check_target(tmp_path)
    with pytest.raises(ConfigError, match="does not exist"):
        check_target(tmp_path / "no" / "x.json")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if not os.access(ro, os.W_OK):  # root may write anyway
            with pytest.raises(ConfigError, match="not writable"):
                check_target(ro / "x.json", "--out")
    finally:
        ro.chmod(0o700)
    check_target("-")
    check_target(None)


def test_a_failed_write_leaves_the_previous_file_whole(tmp_path):
    target = tmp_path / "report.json"
    target.write_text("previous")

    with pytest.raises(TypeError):
        replace_file(target, object())  # type: ignore[arg-type]
    assert target.read_text() == "previous"
    assert [p.name for p in tmp_path.iterdir()] == ["report.json"]  # no temporary left
    replace_file(target, b"new")
    assert target.read_text() == "new"


def test_writing_replaces_whole_or_not_at_all(tmp_path):


    target = tmp_path / "out.csv"
    target.write_text("earlier\n")
    with pytest.raises(KeyboardInterrupt):
        with writing(target) as tmp:
            tmp.write_text("half a file")
            raise KeyboardInterrupt
    assert target.read_text() == "earlier\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]  # no temporary left
    with writing(target) as tmp:
        tmp.write_text("new\n")
    assert target.read_text() == "new\n" and len(list(tmp_path.iterdir())) == 1
