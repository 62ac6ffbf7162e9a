"""The Dockerfile matches the package: parsed (no Docker engine needed), and, in the slow
suite where an engine answers ``docker info``, built and run.

Checked: a slim Python base that satisfies ``requires-python``; a non-root user; the package
installed from the copied sources; every COPY source exists and is not excluded by
``.dockerignore``; the entry point is a ``[project.scripts]`` command and, with CMD, parses as
a ``softsensor run`` command line; the config file CMD names is the reference plant (the
package's copy, which ``config/`` links to, via a COPY) and loads; ``NUMBA_CACHE_DIR`` is set
and created for the user; /config and /data are volumes. The build test builds FROM a local
Debian base when Docker Hub is out of reach (the Dockerfile's BASE argument) and skips,
saying why, where no engine or base is there.
"""

from __future__ import annotations

import fnmatch
import json
import re
import shlex
import tomllib
from pathlib import Path, PurePosixPath
from types import ModuleType

import pytest
from mcap.reader import make_reader
from paths import REPO
from script_modules import load_script

from softsensor.cli import build_parser
from softsensor.plantconfig import load_plant_config

ROOT = REPO


def instructions() -> list[tuple[str, str]]:
    """``(INSTRUCTION, arguments)`` of the Dockerfile, continuation lines joined."""
    text = (ROOT / "Dockerfile").read_text()
    out: list[tuple[str, str]] = []
    buf = ""
    for line in text.splitlines():
        if not buf and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.rstrip().endswith("\\"):
            buf += line.rstrip()[:-1] + " "
            continue
        buf += line
        word, _, rest = buf.strip().partition(" ")
        out.append((word.upper(), rest.strip()))
        buf = ""
    assert not buf, "Dockerfile ends in a continuation line"
    return out


def exec_form(args: str) -> list[str]:
    value = json.loads(args)
    assert isinstance(value, list) and all(isinstance(v, str) for v in value), args
    return value


def of(kind: str) -> list[str]:
    return [a for k, a in instructions() if k == kind]


def stages() -> list[tuple[str, str | None, list[tuple[str, str]]]]:
    """``(FROM image, stage name, instructions)`` of each build stage, in order."""
    out: list[tuple[str, str | None, list[tuple[str, str]]]] = []
    for k, a in instructions():
        if k == "FROM":
            words = a.split()
            name = words[2] if len(words) == 3 and words[1].upper() == "AS" else None
            out.append((words[0], name, []))
        elif out:
            out[-1][2].append((k, a))
    return out


def final_stage() -> list[tuple[str, str]]:
    """The instructions of the image that is shipped (the last stage)."""
    return stages()[-1][2]


def _is_context_copy(args: str) -> bool:
    return not any(w.startswith("--from") for w in shlex.split(args))


def copies() -> list[tuple[list[str], str]]:
    """``(sources, destination)`` of each COPY from the build context, in any stage."""
    out = []
    for args in of("COPY"):
        if _is_context_copy(args):
            words = [w for w in shlex.split(args) if not w.startswith("--")]
            out.append((words[:-1], words[-1]))
    return out


def final_copies() -> list[tuple[str, list[str], str]]:
    """``(WORKDIR, sources, destination)`` of the final stage's COPYs from the context."""
    wd, out = "/", []
    for k, a in final_stage():
        if k == "WORKDIR":
            wd = str(PurePosixPath(wd) / a)
        elif k == "COPY" and _is_context_copy(a):
            words = [w for w in shlex.split(a) if not w.startswith("--")]
            out.append((wd, words[:-1], words[-1]))
    return out


def container_to_repo(path: str) -> Path | None:
    """The repository file that a COPY puts at container ``path`` (None if none does)."""
    target = PurePosixPath(path)
    for wd, sources, dest in final_copies():
        d = PurePosixPath(wd) / dest
        for src in sources:
            repo = ROOT / src
            if repo.is_dir():
                if target.is_relative_to(d):
                    cand = repo / target.relative_to(d)
                    if cand.is_file():
                        return cand
            elif dest.endswith("/") and target == d / PurePosixPath(src).name:
                return repo
            elif not dest.endswith("/") and len(sources) == 1 and target == d:
                return repo
    return None


def arg_defaults() -> dict[str, str]:
    """``ARG NAME=default`` values of the Dockerfile."""
    out = {}
    for a in of("ARG"):
        name, eq, default = a.partition("=")
        if eq:
            out[name.strip()] = default.strip()
    return out


def base_image() -> str:
    """The image the Dockerfile builds FROM when no ``--build-arg`` is given: the final
    stage's, which every stage starts from (directly or through an earlier stage)."""
    names = set()
    for image, name, _ in stages():
        assert image in names or image == stages()[-1][0], f"stage FROM {image}"
        names.add(name)
    base = stages()[-1][0]
    args = arg_defaults()
    m = re.fullmatch(r"\$\{?(\w+)\}?", base)
    if m:
        assert m[1] in args, f"FROM {base}: ARG {m[1]} has no default"
        return args[m[1]]
    return base


def test_base_image_is_slim_python_meeting_requires_python() -> None:
    base = base_image()
    m = re.fullmatch(r"python:(\d+)\.(\d+)-slim(-\w+)?", base)
    assert m, base
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    need = re.fullmatch(r">=\s*(\d+)\.(\d+)", project["requires-python"])
    assert (int(m[1]), int(m[2])) >= (int(need[1]), int(need[2]))


def test_runs_as_a_non_root_user_that_the_image_creates() -> None:
    users = of("USER")
    assert users and users[-1] not in ("root", "0")
    assert any("useradd" in r and users[-1] in r for r in of("RUN"))


def test_copy_sources_exist_and_are_not_docker_ignored() -> None:
    ignore = [p.strip() for p in (ROOT / ".dockerignore").read_text().splitlines()
              if p.strip() and not p.startswith("#")]
    for sources, _ in copies():
        for src in sources:
            assert (ROOT / src).exists(), f"COPY source {src} does not exist"
            for pat in ignore:
                assert not fnmatch.fnmatch(src, pat) and not fnmatch.fnmatch(
                    src, pat.rstrip("/") + "/*"), f"{src} is excluded by .dockerignore {pat}"
    copied = {s for sources, _ in copies() for s in sources}
    assert {"pyproject.toml", "softsensor"} <= copied
    readme = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"].get("readme")
    assert readme is None or readme in copied  # pip install . needs it
    assert any(re.search(r"\bpip install (\S+ )*\.(\s|$)", r) for r in of("RUN"))


def test_entry_point_and_cmd_are_a_valid_softsensor_run_command() -> None:
    (entry,) = [exec_form(a) for a in of("ENTRYPOINT")]
    (cmd,) = [exec_form(a) for a in of("CMD")]
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert entry[0] in scripts and scripts[entry[0]] == "softsensor.cli:main"
    args = build_parser().parse_args([*entry[1:], *cmd])
    assert args.verb == "run"
    repo_config = container_to_repo(args.config)
    assert repo_config is not None, f"no COPY puts a file at {args.config}"
    # the reference plant: the one copy, the package's, that the repository's config/ links to
    assert repo_config.resolve() == (ROOT / "config" / "dryer1.toml").resolve()
    assert load_plant_config(repo_config).unit.name == "dryer1"


def test_numba_cache_dir_is_set_and_owned_by_the_user() -> None:
    env = " ".join(of("ENV"))
    m = re.search(r"NUMBA_CACHE_DIR=(\S+)", env)
    assert m, "NUMBA_CACHE_DIR is not set"
    runs = " ".join(of("RUN"))
    assert re.search(r"mkdir -p [^&]*\"?\$NUMBA_CACHE_DIR", runs)
    assert re.search(r"chown \S+ [^&]*\"?\$NUMBA_CACHE_DIR", runs)


@pytest.mark.parametrize("path", ["/config", "/data"])
def test_config_and_data_are_volumes(path: str) -> None:
    volumes = [v for a in of("VOLUME") for v in exec_form(a)]
    assert path in volumes


def test_files_the_package_build_needs_are_copied() -> None:
    # `pip install .` reads the readme and licence files pyproject.toml names
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    needed = {"pyproject.toml", project["readme"], *project.get("license-files", [])}
    copied = {PurePosixPath(s).name for sources, _ in copies() for s in sources}
    assert needed <= copied, needed - copied


def test_dependencies_have_their_own_layer_before_the_code() -> None:
    """An edit of softsensor/ must not re-download the dependencies: they are installed by a
    RUN that comes after pyproject.toml is copied and before the code is."""
    steps = [(k, a) for _image, _name, body in stages() for k, a in body]
    code = next(i for i, (k, a) in enumerate(steps) if k == "COPY" and "softsensor" in
                shlex.split(a) and _is_context_copy(a))
    pyproject = next(i for i, (k, a) in enumerate(steps) if k == "COPY"
                     and "pyproject.toml" in shlex.split(a))
    deps = [i for i, (k, a) in enumerate(steps) if k == "RUN" and "requirements" in a
            and "pip install" in a]
    assert deps and pyproject < deps[0] < code, (pyproject, deps, code)


def test_the_image_installs_the_runtime_dependencies_only() -> None:
    """The daemon's image has no calibration-only packages: the RUN installs
    ``project.dependencies`` (not an extra), and those hold no Optuna, Matplotlib, PyArrow."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = {re.split(r"[<>=!~\[ ;]", d, maxsplit=1)[0].lower()
             for d in project["dependencies"]}
    assert not names & {"optuna", "matplotlib", "pyarrow", "sqlalchemy"}, names
    assert {"optuna", "matplotlib", "pyarrow"} <= {
        re.split(r"[<>=!~\[ ;]", d, maxsplit=1)[0].lower()
        for d in project["optional-dependencies"]["offline"]}
    runs = " ".join(a for k, a in instructions() if k == "RUN")
    assert "['project']['dependencies']" in runs and "[offline]" not in runs


def test_healthcheck_runs_softsensor_health() -> None:
    (check,) = [a for k, a in final_stage() if k == "HEALTHCHECK"]
    options, _, cmd = check.partition(" CMD ")
    argv = exec_form(cmd)
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert argv[0] in scripts
    args = build_parser().parse_args(argv[1:])
    assert args.verb == "health" and args.connect == ["tcp/127.0.0.1:7447"]
    assert "--timeout" in options and "--interval" in options


# ------------------------------------------------------------------ a real build and run
def _image_benchmark() -> ModuleType:
    """benchmarks/image.py: the build, run and size helpers the slow test shares with it."""
    return load_script(ROOT / "benchmarks" / "image.py")


@pytest.mark.docker
@pytest.mark.slow
def test_image_builds_runs_healthy_read_only_stops_cleanly_and_replays(tmp_path: Path) -> None:
    """Build the image from the Dockerfile as it stands (only BASE changed), then: at most
    600 MB; the daemon with a read-only root filesystem, as a non-root user, becomes healthy
    by its own HEALTHCHECK and stops on SIGTERM with exit code 0 and no traceback; the model
    warm-up uses the cache the build filled; two hours of the demo day replay in it."""
    bench = _image_benchmark()
    try:
        bench.check_engine()
        base = bench.python_base(tmp_path)
    except bench.Unavailable as exc:
        pytest.skip(str(exc))
    bench.build(base)
    size = bench.size_bytes(bench.TAG)
    print(f"image {size / 1e6:.0f} MB, base {bench.size_bytes(base) / 1e6:.0f} MB")
    assert size <= bench.MAX_IMAGE_BYTES, size
    run = bench.run_healthy_and_stop()
    assert run["health"] == "healthy" and run["uid"] == "10001", run
    assert run["exit_code"] == 0 and run["tracebacks"] == 0 and run["stopped_line"], run
    assert run["stop_s"] < 15, run
    tag = bench.TAG
    r = bench.docker("run", "--rm", "--read-only", tag, "--help")
    assert r.returncode == 0 and "--plc" in r.stdout, r.stderr[-2000:]

    # the build compiled the model into NUMBA_CACHE_DIR: a fresh container loads it
    warm = ("import time; t = time.perf_counter(); from softsensor.model import DryerModel; "
            "from softsensor.plantconfig import load_plant_config; "
            "m = DryerModel(load_plant_config()); "
            "m.simulate(m.nominal_inputs()[None, None, :].repeat(2, axis=1)); "
            "print(time.perf_counter() - t)")
    r = bench.docker("run", "--rm", "--read-only", "--entrypoint", "python", tag, "-c", warm)
    assert r.returncode == 0, r.stderr[-2000:]
    assert float(r.stdout.strip().splitlines()[-1]) < 20.0, r.stdout
    # what only calibration needs is not in the image, and the verbs say how to get it
    r = bench.docker("run", "--rm", "--read-only", "--entrypoint", "softsensor", tag,
                     "calibrate", "/nonexistent.mcap", "--out", "/tmp/p.toml")
    assert r.returncode == 2 and "softsensor[offline]" in r.stderr, r.stderr[-500:]

    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o777)  # written by the image's user (uid 10001)
    with open(ROOT / "replay" / "demo-day.mcap", "rb") as f:
        start = make_reader(f).get_summary().statistics.message_start_time
    end = start + 2 * 3600 * 10**9
    r = bench.docker("run", "--rm", "--read-only", "-v", f"{ROOT / 'replay'}:/replay:ro",
                     "-v", f"{out}:/out", "--entrypoint", "softsensor", tag, "replay",
                     "/replay/demo-day.mcap", "--out", "/out/est.mcap", "--end", str(end),
                     timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    with open(out / "est.mcap", "rb") as f:
        ticks = [json.loads(m.data) for _, _, m in
                 make_reader(f).iter_messages(topics=["/softsensor/estimate"])]
    assert len(ticks) >= 10, len(ticks)  # 2 h of 600 s ticks
    assert all(0.0 < t["moisture_out"] < 0.2 for t in ticks), ticks[-1]
