"""``softsensor advise`` (``softsensor/apps/advise.py``): its one-line refusals of bad
input."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "independent_plant_params.toml"


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "softsensor.cli", *args],
                          capture_output=True, text=True, timeout=120)


def _one_line(r, code: int, words: str) -> None:
    assert r.returncode == code, r.stderr
    assert words in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_advise_refuses_bad_input_with_one_line(tmp_path):
    _one_line(_cli("advise", str(tmp_path / "d.mcap"), "--params", str(FIXTURE)), 2,
              "no such file")
    _one_line(_cli("advise", "--params", str(FIXTURE)), 2, "give one DAY.mcap")
    bare = tmp_path / "p.toml"
    bare.write_text("[parameters.mult_D]\nvalue = 1.0\n")
    _one_line(_cli("advise", str(tmp_path / "d.mcap"), "--params", str(bare)), 2,
              "no [model_error] table")
    cfg = tmp_path / "plant.toml"
    cfg.write_text(Path(__file__).resolve().parents[2].joinpath(
        "softsensor/data/dryer1.toml").read_text()
        + "\n[advisor]\nmoisture_target = 0.2\nmoisture_max = 0.16\n")
    _one_line(_cli("advise", str(tmp_path / "d.mcap"), "--params", str(FIXTURE), "--config",
                   str(cfg)), 2, "moisture_max (0.16) must be above moisture_target")
    bad = tmp_path / "i.json"
    bad.write_text("{}")
    day = tmp_path / "bad.mcap"
    day.write_bytes(b"not an mcap file")
    r = _cli("advise", str(day), "--params", str(FIXTURE), "--identify", str(bad))
    assert r.returncode == 2 and str(day) in r.stderr and "Traceback" not in r.stderr
