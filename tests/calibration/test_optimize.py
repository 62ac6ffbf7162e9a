"""The Optuna study (``softsensor/calibration/optimize.py``): pruning, failed solves, bounds,
resume, two workers on one journal file; the search model's substeps. The chunked runs it
prunes on: ``test_chunked_run.py``; the polish after it: ``test_refine.py``; ``calibrate``'s
one-line errors: ``tests/apps/test_calibrate.py``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import optuna
import pytest
from optuna.trial import TrialState
from paths import REPO
from synthetic_days import TRUTH

from softsensor.calibration.dataset import segment_from_day
from softsensor.calibration.optimize import (
    FAILED_COST,
    StudySettings,
    count_trials,
    data_fingerprint,
    n_finished,
    open_storage,
    open_study,
    run_trials,
    search_space,
)
from softsensor.errors import ConfigError
from softsensor.plantconfig import PARAMETER_NAMES

optuna.logging.set_verbosity(optuna.logging.WARNING)


@pytest.fixture(scope="module")
def day6_file(day6, tmp_path_factory):
    return day6.write(tmp_path_factory.mktemp("days") / "day6.mcap")


def test_study_prunes_keeps_bounds_and_starts_from_the_config(model, segment, config, eq4):
    settings = StudySettings(n_trials=24, seed=4, progress=False, n_chunks=4)
    study, created = open_study(settings, config, data_fingerprint([segment], config))
    assert created
    report = run_trials(study, model, [segment], config, settings, eq4)
    trials = study.get_trials()
    assert n_finished(study) == 24 == report.trials
    assert trials[0].user_attrs["origin"] == "config"
    assert trials[0].params == {n: config.parameters[n].value for n in PARAMETER_NAMES}
    counts = count_trials(study)
    assert counts["pruned"] == report.pruned > 0 and counts["complete"] == report.complete
    space = search_space(config)
    for t in trials:
        for name, v in t.params.items():
            assert space[name].low <= v <= space[name].high
        if t.state == TrialState.PRUNED:
            assert t.intermediate_values and max(t.intermediate_values) < 3
        else:
            assert t.user_attrs["rmse_moisture_out"] > 0
    assert all(space[n].log for n in PARAMETER_NAMES)
    assert report.windows_simulated < report.windows_full  # pruning saved model time


class _FailingModel:
    """Wraps a model; members with mult_D < 0.05 fail (NaN) from their second window."""

    def __init__(self, model):
        self.model = model

    def simulate(self, U, theta, state0=None, raise_on_failure=True, **kw):
        Y, x = self.model.simulate(U, theta, state0=state0, raise_on_failure=False, **kw)
        bad = np.atleast_2d(theta)[:, 0] < 0.05
        Y[bad, 1:] = np.nan
        return Y, x


def test_failed_solves_are_pruned_with_a_high_cost(model, segment, config, eq4):
    settings = StudySettings(n_trials=4, seed=0, progress=False, n_chunks=2)
    study, _ = open_study(settings, config, "x")
    study.enqueue_trial({**TRUTH, "mult_D": 0.02})
    study.enqueue_trial({**TRUTH, "mult_D": 0.03})
    run_trials(study, _FailingModel(model), [segment], config, settings, eq4)
    failed = [t for t in study.get_trials() if t.user_attrs.get("solver_failed")]
    assert len(failed) == 2
    for t in failed:
        assert t.state == TrialState.PRUNED and t.intermediate_values[0] == FAILED_COST
    assert study.best_value < 1.0


def test_resume_and_data_fingerprint(tmp_path, model, segment, config, eq4):
    url = f"journal:{tmp_path / 'study.log'}"
    fp = data_fingerprint([segment], config)
    s1 = StudySettings(n_trials=5, seed=1, storage=url, progress=False, study_name="r")
    study, created = open_study(s1, config, fp)
    run_trials(study, model, [segment], config, s1, eq4)
    first = [t.params for t in study.get_trials()]
    s2 = StudySettings(n_trials=8, seed=1, storage=url, progress=False, study_name="r")
    study2, created2 = open_study(s2, config, fp)
    assert created and not created2
    report = run_trials(study2, model, [segment], config, s2, eq4)
    assert report.trials == 3 and n_finished(study2) == 8
    assert [t.params for t in study2.get_trials()[:5]] == first
    with pytest.raises(ConfigError, match="made on other data"):
        open_study(s2, config, "another")
    with pytest.raises(ConfigError, match="journal file"):
        open_storage("study.txt")
    with pytest.raises(ConfigError, match="does not exist"):
        open_storage(str(tmp_path / "no" / "s.log"))
    # a database URL opens Optuna's RDB storage, which creates and keeps the study there
    db = tmp_path / "s.db"
    rdb = open_storage(f"sqlite:///{db}")
    assert isinstance(rdb, optuna.storages.RDBStorage) and db.is_file()
    optuna.create_study(storage=rdb, study_name="kept")
    assert [s.study_name for s in optuna.get_all_study_summaries(open_storage(
        f"sqlite:///{db}"))] == ["kept"]


def test_a_study_is_not_resumed_under_another_structure(tmp_path, segment, config):
    """The fingerprint hashed the data, the bounds and the objective but not the plant's
    structure: a study resumed under a PARAMS.toml's ``[structure]`` (a longer cyclone
    hold-up, another drying law) took the trials of another model as its own (issue 37).
    Every key of the structural library now changes it, and such a study is refused."""
    from softsensor.model.structure import structure_space

    fp = data_fingerprint([segment], config)
    assert data_fingerprint([segment], config.with_keys({"unit.name": "dryer2"})) == fp
    changed = []
    for alt in structure_space():
        keys = {**alt.sets, **{r.key: r.high for r in alt.free}}
        for key, value in keys.items():
            section, name = key.split(".")
            if getattr(getattr(config, section), name) == value:
                continue
            other = config.with_keys({key: value})
            assert other.bounds().tolist() == config.bounds().tolist()
            assert data_fingerprint([segment], other) != fp, key
            changed.append(key)
    assert {"cyclone.hold_up_time", "fiber.drying_law", "fiber.bound_fraction",
            "environment.ambient_loss_slope"} <= set(changed)
    settings = StudySettings(n_trials=1, storage=f"journal:{tmp_path / 'study.log'}",
                             progress=False, study_name="s")
    open_study(settings, config, fp)
    longer = config.with_keys({"cyclone.hold_up_time": 12.0})
    with pytest.raises(ConfigError, match="made on other data, bounds or plant structure"):
        open_study(settings, longer, data_fingerprint([segment], longer))


def test_two_workers_share_one_journal_study(tmp_path, day6_file):
    """Two processes join one study through a journal file; they start together, split the
    trials, and the trials add up to the study's target."""
    journal = tmp_path / "shared.log"
    go = tmp_path / "go"
    worker = textwrap.dedent(f"""
        import sys, time, pathlib
        from softsensor.cli import main  # imports numba and the model before the start
        import softsensor.model.kernels  # noqa
        pathlib.Path(sys.argv[1] + ".ready").touch()
        while not pathlib.Path({str(go)!r}).exists():
            time.sleep(0.05)
        sys.exit(main(["calibrate", {str(day6_file)!r}, "--trials", "16", "--quiet",
                       "--storage", "journal:{journal}", "--study-name", "w",
                       "--no-polish", "--no-identify", "--seed", "3",
                       "--out", sys.argv[1], "--json", "-"]))
    """)
    outs = [tmp_path / f"p{i}.toml" for i in range(2)]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs = [subprocess.Popen([sys.executable, "-c", worker, str(o)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env=env) for o in outs]
    deadline = time.time() + 120
    while not all(Path(str(o) + ".ready").exists() for o in outs):
        assert time.time() < deadline, "workers did not start"
        assert all(p.poll() is None for p in procs), procs[0].communicate()
        time.sleep(0.1)
    go.touch()
    results = [p.communicate(timeout=300) for p in procs]
    for p, (_out, err) in zip(procs, results, strict=True):
        assert p.returncode == 0, err
    docs = [json.loads(out) for out, _ in results]
    study = optuna.load_study(study_name="w", storage=open_storage(f"journal:{journal}"))
    finished = [t for t in study.get_trials() if t.state in (TrialState.COMPLETE,
                                                             TrialState.PRUNED)]
    by_worker: dict[int, int] = {}
    for t in study.get_trials():
        by_worker[t.user_attrs["worker"]] = by_worker.get(t.user_attrs["worker"], 0) + 1
    assert 16 <= len(finished) <= 17  # a worker may start one trial as the other fills it
    assert sum(d["trials_this_process"] for d in docs) == len(study.get_trials())
    assert sorted(by_worker.values()) == sorted(d["trials_this_process"] for d in docs)
    assert len(by_worker) == 2 and min(by_worker.values()) >= 3
    assert all(t.state != TrialState.RUNNING for t in study.get_trials())
    # the two workers proposed different trials (different sampler seeds)
    params = [tuple(sorted(t.params.items())) for t in study.get_trials()]
    assert len(set(params)) == len(params)


def test_search_model_with_one_wall_substep_keeps_the_settings_claim():
    """The TPE search runs the model with ``[calibration] search_wall_substeps`` (1): on the
    demo day its outputs stay within the settings' claim (0.01 K, 2e-5 kg/kg) of the full
    model's, and it is a copy, so the full model keeps its substeps for polish and validation.
    """
    from softsensor.calibration.calibration_run import search_model
    from softsensor.calibration.settings import calibration_settings
    from softsensor.model import DryerModel
    from softsensor.plantconfig import load_plant_config
    from softsensor.recording.mcap_day import read_day

    cfg = load_plant_config()
    seg = segment_from_day(read_day(REPO / "replay" / "demo-day.mcap"),
                           cfg, source="demo")
    full = DryerModel(cfg, threads=1)
    fast = search_model(full, calibration_settings(cfg))
    assert fast is not full and fast.wall_substeps == 1
    assert full.wall_substeps == cfg.solver.wall_substeps == 4
    Y_full, _ = full.simulate(seg.U[None])
    Y_fast, _ = fast.simulate(seg.U[None])
    d = np.abs(Y_fast - Y_full)[0].max(axis=0)
    assert d[0] < 0.01 and d[1] < 0.01 and d[2] < 2e-5, d
    assert d[0] > 0  # the copy really runs with fewer substeps
