"""Calibration on several machines: two ``softsensor calibrate`` workers share one Optuna
study in a real PostgreSQL (Debian's server, a private cluster on 127.0.0.1 in a temporary
folder, started and stopped here).

The study must hold the union of both workers' trials (one budget, no trial lost or run
twice), and its best must be as good as one worker alone would reach with the same budget,
within TPE's own noise (measured here: single-worker studies of three seeds).

Skipped, with the reason, where the server binaries (``apt install postgresql``) or the
driver (``psycopg[binary]``, in the ``test`` extra: SQLAlchemy 2.1, under Optuna's RDB
storage, reads ``postgresql://`` as psycopg 3) are missing; marked ``postgresql``, so CI runs it
by name after the default suite.
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from softsensor.bus.zenoh_bus import free_port
from softsensor.cli import main

pytestmark = pytest.mark.postgresql

TRIALS = 40  # the shared budget (and each single worker's)
SOFTSENSOR = [sys.executable, "-m", "softsensor.cli"]


def _server_binaries() -> Path | None:
    found = shutil.which("initdb") or next(iter(sorted(
        glob.glob("/usr/lib/postgresql/*/bin/initdb"), reverse=True)), None)
    return None if found is None else Path(found).parent


@contextlib.contextmanager
def private_cluster():
    """A PostgreSQL cluster on 127.0.0.1 in a temporary folder; yields its URL."""
    pytest.importorskip("psycopg", reason="the PostgreSQL driver psycopg is not installed "
                                          "(pip install -e '.[test]')")
    bindir = _server_binaries()
    if bindir is None:
        pytest.skip("PostgreSQL server binaries (initdb, pg_ctl) not found: "
                    "apt install postgresql")
    run_as: dict = {}
    if os.geteuid() == 0:  # the server refuses to run as root: run it as 'postgres'
        try:
            pw = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run the server")
        run_as = {"user": pw.pw_uid, "group": pw.pw_gid, "extra_groups": []}
    top = Path(tempfile.mkdtemp(prefix="softsensor-pg-"))
    data, sock = top / "data", top / "sock"
    sock.mkdir()
    if run_as:
        os.chmod(top, 0o755)
        for p in (top, sock):
            os.chown(p, run_as["user"], run_as["group"])
    port = free_port()

    def pg(*args: str, timeout: float = 60) -> None:
        done = subprocess.run(list(args), capture_output=True, text=True, timeout=timeout,
                              check=False, **run_as)
        assert done.returncode == 0, f"{args[0]}: {done.stderr.strip() or done.stdout}"

    try:
        pg(str(bindir / "initdb"), "-D", str(data), "-U", "postgres", "--auth=trust",
           "-E", "UTF8", "--no-sync")
        pg(str(bindir / "pg_ctl"), "-D", str(data), "-l", str(top / "server.log"), "-w",
           "-t", "30", "-o", f"-c listen_addresses=127.0.0.1 -p {port} -k {sock} "
                             f"-c fsync=off -c max_connections=20", "start")
        try:
            yield f"postgresql://postgres@127.0.0.1:{port}/postgres"
        finally:
            pg(str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop")
    finally:
        shutil.rmtree(top, ignore_errors=True)


def _calibrate(day: Path, out: Path, *extra: str) -> list[str]:
    return [*SOFTSENSOR, "calibrate", str(day), "--trials", str(TRIALS), "--out",
            str(out.with_suffix(".toml")), "--json", str(out), "--no-polish", "--no-identify",
            "--force", "--quiet", *extra]


def test_two_workers_share_one_postgresql_study(tmp_path: Path):
    day = tmp_path / "day.mcap"
    assert main(["simulate", "--hours", "8", "--seed", "5", "--out", str(day)]) == 0
    with private_cluster() as url:
        shared = ["--storage", url, "--study-name", "shared"]
        import optuna

        # Optuna makes its tables on first use; two workers started in the same second on an
        # empty database race at it (one fails: duplicate key in pg_type), so the tables are
        # made first, as the several-machines page tells a site to (start one worker, then the
        # others)
        optuna.storages.RDBStorage(url).engine.dispose()
        workers = [subprocess.Popen(_calibrate(day, tmp_path / f"w{k}.json", *shared),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                    text=True) for k in (1, 2)]
        for w in workers:
            _, err = w.communicate(timeout=300)
            assert w.returncode == 0, err[-2000:]
        storage = optuna.storages.RDBStorage(url)
        study = optuna.load_study(study_name="shared", storage=storage)
        finished = [t for t in study.get_trials(deepcopy=False) if t.state.is_finished()]
        best = study.best_value
        storage.engine.dispose()  # close its connections before the cluster stops
    w = [json.loads((tmp_path / f"w{k}.json").read_text()) for k in (1, 2)]
    # the union: one budget, every trial of both workers in the study, none twice
    assert all(x["trials_this_process"] >= 1 for x in w), w
    assert sum(x["trials_this_process"] for x in w) == len(finished)
    assert TRIALS <= len(finished) <= TRIALS + 2  # each may overshoot by its one batch
    assert len({t.number for t in finished}) == len(finished)
    assert best == pytest.approx(min(x["tpe_best"]["objective"] for x in w), rel=1e-12)
    # as good as one worker with the same budget, within TPE's noise (three seeds)
    singles = []
    for seed in (0, 1, 2):  # in this process: the same command, without a start-up each
        out = tmp_path / f"single{seed}.json"
        assert main(_calibrate(day, out, "--seed", str(seed))[len(SOFTSENSOR):]) == 0
        singles.append(json.loads(out.read_text())["tpe_best"]["objective"])
    noise = max(singles) - min(singles)
    assert best <= max(singles) + noise, (best, singles)
