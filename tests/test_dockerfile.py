"""The Dockerfile matches the package (no Docker engine needed: the file is parsed).

Checked: a slim Python base that satisfies ``requires-python``; a non-root user; the package
installed from the copied sources; every COPY source exists and is not excluded by
``.dockerignore``; the entry point is a ``[project.scripts]`` command and, with CMD, parses as
a ``softsensor run`` command line; the config file CMD names is shipped by the repository (via
a COPY) and loads; ``NUMBA_CACHE_DIR`` is set and created for the user; /config and /data are
volumes.
"""

from __future__ import annotations

import fnmatch
import json
import re
import shlex
import tomllib
from pathlib import Path, PurePosixPath

import pytest

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


def test_base_image_is_slim_python_meeting_requires_python() -> None:
    (base,) = of("FROM")
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
