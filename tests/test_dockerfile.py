"""The Dockerfile matches the package: parsed (no Docker engine needed), and, in the slow
suite where an engine answers ``docker info``, built and run.

Checked: a slim Python base that satisfies ``requires-python``; a non-root user; the package
installed from the copied sources; every COPY source exists and is not excluded by
``.dockerignore``; the entry point is a ``[project.scripts]`` command and, with CMD, parses as
a ``softsensor run`` command line; the config file CMD names is shipped by the repository (via
a COPY) and loads; ``NUMBA_CACHE_DIR`` is set and created for the user; /config and /data are
volumes. The build test builds FROM a local Debian base when Docker Hub is out of reach
(the Dockerfile's BASE argument) and skips, saying why, where no engine or base is there.
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
import shlex
import shutil
import subprocess
import tomllib
from pathlib import Path, PurePosixPath

import pytest
from mcap.reader import make_reader

from softsensor.cli import build_parser
from softsensor.plantconfig import load_plant_config

ROOT = Path(__file__).resolve().parents[1]


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


def copies() -> list[tuple[list[str], str]]:
    """``(sources, destination)`` of each COPY from the build context."""
    out = []
    for args in of("COPY"):
        words = [w for w in shlex.split(args) if not w.startswith("--")]
        assert not any(w.startswith("--from") for w in shlex.split(args))
        out.append((words[:-1], words[-1]))
    return out


def workdir_before_copies() -> dict[int, str]:
    wd, out, i = "/", {}, 0
    for k, a in instructions():
        if k == "WORKDIR":
            wd = str(PurePosixPath(wd) / a)
        elif k == "COPY":
            out[i] = wd
            i += 1
    return out


def container_to_repo(path: str) -> Path | None:
    """The repository file that a COPY puts at container ``path`` (None if none does)."""
    target = PurePosixPath(path)
    wds = workdir_before_copies()
    for i, (sources, dest) in enumerate(copies()):
        d = PurePosixPath(wds[i]) / dest
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
    """The image the Dockerfile builds FROM when no ``--build-arg`` is given."""
    (base,) = of("FROM")
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
    assert repo_config.relative_to(ROOT).parts[0] == "config"
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


# ------------------------------------------------------------------ a real build and run
#: The Debian base the build test puts Python on when Docker Hub is out of reach (README of
#: the test below says how to make it); ``SOFTSENSOR_DOCKER_BASE`` names another.
LOCAL_BASE = os.environ.get("SOFTSENSOR_DOCKER_BASE", "local/bookworm:base")
HOST_CA = Path("/etc/ssl/certs/ca-certificates.crt")
#: Python on the Debian base, as the Dockerfile expects of BASE (``pip`` and ``python`` on
#: PATH). The host's CA bundle goes into this test-only layer so that pip reaches the package
#: index through the host's TLS proxy; the default image never sees it.
PYTHON_LAYER = """\
FROM {base}
RUN apt-get update && apt-get install -y --no-install-recommends python3 python3-venv \\
    && apt-get clean && rm -rf /var/lib/apt/lists/* && python3 -m venv /opt/python
COPY ca.crt /etc/ssl/certs/host-ca.crt
ENV PATH=/opt/python/bin:$PATH PIP_CERT=/etc/ssl/certs/host-ca.crt
"""


def _docker(*args: str, timeout: float = 120, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout,
                          **kw)


def _engine_or_skip() -> None:
    if shutil.which("docker") is None:
        pytest.skip("no docker client on PATH")
    info = _docker("info", timeout=30)
    if info.returncode != 0:
        lines = (info.stderr or info.stdout).strip().splitlines()
        pytest.skip(f"no Docker engine answers `docker info`: {lines[-1] if lines else '?'}")


def _python_base(tmp_path: Path) -> str:
    """An image with Python to build FROM: the local Debian base with the Python layer, or
    the public default when the engine already holds it."""
    if _docker("image", "inspect", LOCAL_BASE).returncode == 0:
        ctx = tmp_path / "python-layer"
        ctx.mkdir()
        (ctx / "Dockerfile").write_text(PYTHON_LAYER.format(base=LOCAL_BASE))
        shutil.copyfile(HOST_CA, ctx / "ca.crt")
        tag = "softsensor-test/python:bookworm"
        r = _docker("build", "-t", tag, str(ctx), timeout=1200)
        assert r.returncode == 0, r.stderr[-3000:]
        return tag
    if _docker("image", "inspect", base_image()).returncode == 0:
        return base_image()
    pytest.skip(f"neither {LOCAL_BASE} nor {base_image()} is in the engine (make the first "
                "with `debootstrap --variant=minbase bookworm ROOTFS` and `tar -C ROOTFS -c . "
                f"| docker import - {LOCAL_BASE}`)")


@pytest.mark.slow
def test_image_builds_runs_its_help_and_replays_part_of_the_demo_day(tmp_path: Path) -> None:
    """Build the image from the Dockerfile as it stands (only BASE changed), then run it: the
    entry point's help, the model warm-up from the cache the build filled, and two hours of
    the demo day through ``softsensor replay`` as the image's unprivileged user."""
    _engine_or_skip()
    base = _python_base(tmp_path)
    tag = "softsensor-test/softsensor:latest"
    r = _docker("build", "--build-arg", f"BASE={base}", "-t", tag, str(ROOT), timeout=2400)
    assert r.returncode == 0, r.stderr[-3000:]

    r = _docker("run", "--rm", tag, "--help")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "--plc" in r.stdout and "--listen" in r.stdout, r.stdout[:2000]

    # the build compiled the model into NUMBA_CACHE_DIR: a fresh container loads it
    warm = ("import time; t = time.perf_counter(); from softsensor.model import DryerModel; "
            "from softsensor.plantconfig import load_plant_config; "
            "m = DryerModel(load_plant_config()); "
            "m.simulate(m.nominal_inputs()[None, None, :].repeat(2, axis=1)); "
            "print(time.perf_counter() - t)")
    r = _docker("run", "--rm", "--entrypoint", "python", tag, "-c", warm)
    assert r.returncode == 0, r.stderr[-2000:]
    assert float(r.stdout.strip().splitlines()[-1]) < 20.0, r.stdout

    out = tmp_path / "out"
    out.mkdir()
    out.chmod(0o777)  # written by the image's user (uid 10001)
    with open(ROOT / "replay" / "demo-day.mcap", "rb") as f:
        start = make_reader(f).get_summary().statistics.message_start_time
    end = start + 2 * 3600 * 10**9
    r = _docker("run", "--rm", "-v", f"{ROOT / 'replay'}:/replay:ro", "-v", f"{out}:/out",
                "--entrypoint", "softsensor", tag, "replay", "/replay/demo-day.mcap",
                "--out", "/out/est.mcap", "--end", str(end), timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    with open(out / "est.mcap", "rb") as f:
        ticks = [json.loads(m.data) for _, _, m in
                 make_reader(f).iter_messages(topics=["/softsensor/estimate"])]
    assert len(ticks) >= 10, len(ticks)  # 2 h of 600 s ticks
    assert all(0.0 < t["moisture_out"] < 0.2 for t in ticks), ticks[-1]
