"""``softsensor diagnose`` (``softsensor/apps/diagnose.py``): its options and its one-line
refusals."""

from __future__ import annotations

import subprocess
import sys


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "softsensor.cli", *args],
                          capture_output=True, text=True, timeout=120)


def test_cli_refuses_bad_input_with_one_line(tmp_path):
    r = _cli("diagnose", "--params", str(tmp_path / "missing.toml"), str(tmp_path / "d.mcap"),
             "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and "no such file" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr
    r = _cli("diagnose", str(tmp_path / "d.mcap"), "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and "--calibrate-on" in r.stderr
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    params = tmp_path / "p.toml"
    params.write_text("[parameters.mult_D]\nvalue = 1.0\n")
    r = _cli("diagnose", "--params", str(params), str(bad), "--json", str(tmp_path / "r.json"))
    assert r.returncode == 2 and str(bad) in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_diagnose_calibrates_with_the_trials_calibrate_uses():
    """``diagnose --calibrate-on`` runs the same calibration as ``calibrate`` (issue 24 item
    8: it used 40 trials where calibrate used the paper's 200)."""
    import argparse

    from softsensor.apps.calibrate import add_calibrate_arguments
    from softsensor.apps.diagnose import add_diagnose_arguments

    cal, diag = argparse.ArgumentParser(), argparse.ArgumentParser()
    add_calibrate_arguments(cal)
    add_diagnose_arguments(diag)
    assert cal.get_default("trials") == diag.get_default("trials") == 200
