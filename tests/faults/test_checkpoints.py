"""Fault injection (issue 14, item 4): checkpoints verified before use.

A checkpoint with flipped bytes, a NaN filter state, ``x = 1e308`` or a non-positive-definite
covariance used to stop the daemon with a traceback or, worse, be accepted (no estimate ever
again; ``moisture_out = 1e+308`` published). Each is now refused with a reason: the daemon
moves the file aside and starts afresh, or with ``--resume=required`` stops with one line.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from softsensor.errors import ConfigError
from softsensor.plantconfig import load_plant_config
from softsensor.service.build import make_service
from softsensor.service.checkpoint import CheckpointStore, state_digest
from softsensor.service.daemon import Daemon
from softsensor.service.settings import service_settings
from softsensor.service.warmup import warm_up


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict:
    """A real checkpoint of a service that ran a few ticks."""
    cfg = load_plant_config()
    settings = service_settings(cfg)
    service = make_service(cfg, settings)
    warm_up(lambda: service, cfg)  # ticks a short synthetic stretch
    path = tmp_path_factory.mktemp("ckpt") / "checkpoint.json"
    CheckpointStore(path).save(service.checkpoint(), saved_at_ns=1_767_571_200 * 10**9,
                               unit="dryer1")
    return json.loads(path.read_text())


def _daemon(tmp_path: Path, doc: dict | str, resume="auto") -> tuple[Daemon, Path]:
    cfg = load_plant_config()
    path = tmp_path / "checkpoint.json"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    settings = service_settings(cfg).with_overrides(checkpoint=str(path))
    return Daemon(cfg, settings, resume=resume), path


def _edit_state(doc: dict, fn) -> dict:
    doc = json.loads(json.dumps(doc))
    fn(doc["service"]["estimator"]["state"])
    doc["sha256"] = state_digest(doc["service"])  # a consistent file with a bad state
    return doc


def test_a_good_checkpoint_resumes(saved, tmp_path):
    d, _ = _daemon(tmp_path, saved)
    doc = d._load_checkpoint()
    assert doc is not None
    service = d._service(doc, 10.0)
    assert service.stats.ticks == saved["service"]["stats"]["ticks"] > 0 and d.resumed


def _bad_docs(saved: dict) -> dict[str, dict | str]:
    flipped = json.dumps(saved).replace('"ticks":', '"ticks" :', 1)
    edited = json.loads(json.dumps(saved))
    edited["service"]["stats"]["ticks"] += 1  # content changed, checksum not
    return {
        "not json": flipped[: len(flipped) // 2],
        "checksum": edited,
        "nan state": _edit_state(saved, lambda st: st["x"].__setitem__(0, float("nan"))),
        "huge state": _edit_state(saved, lambda st: st["x"].__setitem__(0, 1e308)),
        "not positive definite": _edit_state(
            saved, lambda st: st["P"][0].__setitem__(0, -1.0)),
        "no time": dict(saved, saved_at_ns="soon"),
    }


@pytest.mark.parametrize("case", ["not json", "checksum", "nan state", "huge state",
                                  "not positive definite", "no time"])
def test_a_bad_checkpoint_is_moved_aside_and_the_daemon_starts_afresh(saved, tmp_path, case,
                                                                     caplog):
    d, path = _daemon(tmp_path, _bad_docs(saved)[case])
    service = d._service(d._load_checkpoint(), 10.0)
    assert service.stats.ticks == 0 and not d.resumed  # fresh
    assert not path.exists() and len(list(tmp_path.glob("checkpoint.json.bad-*"))) == 1
    assert any("checkpoint_rejected" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("case", ["not json", "nan state"])
def test_resume_required_stops_with_one_line(saved, tmp_path, case):
    d, path = _daemon(tmp_path, _bad_docs(saved)[case], resume="required")
    with pytest.raises(ConfigError, match="--resume=required") as err:
        d._service(d._load_checkpoint(), 10.0)
    assert "\n" not in str(err.value) and path.exists()  # left where it was


def test_a_daemon_whose_checkpoint_was_rejected_does_not_say_it_resumed(saved, tmp_path):
    """Issue 25, item 8: the ``started`` line (and ``softsensor run``'s first line) said
    ``resumed=true`` after the checkpoint had been moved aside."""
    import asyncio

    from daemon_harness import running_daemon

    (tmp_path / "ckpt.json").write_text(json.dumps(_bad_docs(saved)["nan state"]))
    got = {}

    async def main() -> None:
        async with running_daemon(tmp_path, ticks=0) as r:
            got["resumed"] = r.daemon.info.resumed

    asyncio.run(asyncio.wait_for(main(), 120))
    assert got["resumed"] is False
    assert len(list(tmp_path.glob("ckpt.json.bad-*"))) == 1


_ENDLESS = """
import resource, sys
from softsensor.errors import ConfigError
from softsensor.service.checkpoint import CheckpointStore
resource.setrlimit(resource.RLIMIT_AS, (1 << 31, 1 << 31))
try:
    CheckpointStore(sys.argv[1]).load()
except ConfigError as exc:
    print("ConfigError", exc)
except BaseException as exc:
    print(type(exc).__name__, exc)
"""


@pytest.mark.parametrize("kind", ["endless", "huge"])
def test_a_checkpoint_is_read_with_a_size_cap(tmp_path, kind):
    """Issue 49 (fifth probe): a checkpoint pointing at an endless file grew ``replay`` to
    13 GB. Now a checkpoint is read to a cap (a real one is about 50 kB) and a file that is
    not a regular one is refused; both with a one-line error naming the file."""
    import subprocess
    import sys

    from softsensor.service.checkpoint import MAX_BYTES

    path = tmp_path / "checkpoint.json"
    if kind == "endless":
        path.symlink_to("/dev/zero")
    else:
        with path.open("wb") as f:  # sparse: no disk taken
            f.truncate(4 * MAX_BYTES)
    r = subprocess.run([sys.executable, "-c", _ENDLESS, str(path)], capture_output=True,
                       text=True, timeout=120)
    said = r.stdout.strip()
    assert said.startswith(f"ConfigError {path}: "), (said, r.stderr[-500:])
    assert ("not a regular file" if kind == "endless" else f"more than {MAX_BYTES}") in said
    assert len(said.splitlines()) == 1
