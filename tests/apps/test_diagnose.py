"""``softsensor diagnose`` (``softsensor/apps/diagnose.py``): its options and its one-line
refusals."""

from __future__ import annotations

import subprocess
import sys

import pytest


def _cli(*args, timeout: float = 120.0):
    return subprocess.run([sys.executable, "-m", "softsensor.cli", *args],
                          capture_output=True, text=True, timeout=timeout)


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


@pytest.mark.slow
def test_learn_normal_keeps_the_history_beside_the_params_for_diagnose_and_validate(tmp_path):
    """``softsensor learn-normal`` (issue 48 item 1) judges each history day against a normal
    without it and writes ``PARAMS.plant-normal.json``; ``diagnose`` and ``validate`` with
    those ``--params`` then judge a day against it (two 7 h history days of the independent
    plant, too few to know its normal: the report and the line say so)."""
    import json

    from softsensor.calibration.dataset import segment_from_day
    from softsensor.calibration.model_error_fit import fit_model_error
    from softsensor.calibration.params_file import params_document, write_params
    from softsensor.model.dryer import DryerModel
    from softsensor.plant.independent import simulate_independent_day
    from softsensor.plantconfig import load_plant_config

    cfg = load_plant_config()
    days = [simulate_independent_day(cfg, 7.0, s, plant_seed=8207) for s in (1, 2, 3)]
    paths = [str(tmp_path / f"d{i}.mcap") for i in range(len(days))]
    for d, p in zip(days, paths, strict=True):
        d.write(p)
    segs = [segment_from_day(d, cfg, source=p) for d, p in zip(days[:2], paths, strict=False)]
    me = fit_model_error(DryerModel(cfg), segs, cfg.parameter_vector(),
                         float(cfg.nominal.moisture_in))
    params = write_params(tmp_path / "p.toml", params_document(
        cfg, {n: cfg.parameters[n].value for n in cfg.parameters}, {},
        model_error=me.to_table()))
    r = _cli("learn-normal", *paths[:2], "--params", str(params), "--quiet", timeout=600)
    assert r.returncode == 0, r.stderr
    kept = json.loads((tmp_path / "p.plant-normal.json").read_text())
    assert [d["source"] for d in kept["days"]] == paths[:2]
    assert set(kept["days"][0]["errors"]) == {"sensor", "open_loop"}
    r = _cli("diagnose", paths[2], "--params", str(params), "--json", str(tmp_path / "r.json"),
             "--quiet", timeout=600)
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["plant_normal"]["history_days"] == 2
    assert report["plant_normal"]["enough"] is False
    assert "Too little history to know this plant's normal (2 history day(s)" in r.stderr
    r = _cli("validate", paths[2], "--params", str(params), "--json", str(tmp_path / "v.json"),
             timeout=600)
    assert r.returncode == 0, r.stderr
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["history"]["history_days"] == 2 and v["history"]["note"] is None
    assert "Against this plant's 2 history days in the same mode" in r.stderr
    # parameters changed after the normal was learned: it is not used
    params.write_text(params.read_text() + "\n")
    r = _cli("diagnose", paths[2], "--params", str(params), "--json", str(tmp_path / "r.json"),
             timeout=600)
    assert "learned for other parameters" in r.stderr
