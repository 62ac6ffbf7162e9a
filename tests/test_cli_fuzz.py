"""Every verb, fed random options and hostile files, answers with one line (issue 14, item 6).

Hypothesis draws, for each verb of :func:`softsensor.cli.build_parser`, a command line from
the verb's own options: numbers that are not (``nan``, ``inf``, ``1e400``, 5000 digits,
negative seeds and ports), choices that are not, and paths to what a user can get wrong (a
folder, a missing folder, an empty file, bytes that are not UTF-8, a truncated MCAP file,
garbage CSV). Whatever the draw, ``softsensor`` must end with an exit status, never a
traceback, and a failure must be one line starting with ``softsensor`` that is a designed
message, not the catch-all for bugs ("unexpected ..."). Derandomised, so the default suite is
deterministic; ``-m slow`` runs many more draws.

``run`` is driven up to the point where the daemon would start (its ``Daemon.run`` replaced
by an immediate return), ``plant-server`` by a fixed list of bad command lines (it simulates a
day before it listens).
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from softsensor.cli import build_parser, main

VERBS = [v for v in build_parser()._subparsers._group_actions[0].choices  # type: ignore[union-attr]
         if v != "plant-server"]
FLOATS = ["nan", "inf", "-inf", "-1", "0", "1e400", "1e308", "0.25", "x", "1" * 5000]
INTS = ["-1", "0", "3", "99999", "4294967296", "x", "7" * 5000]
#: Options put first (a draw of the same option comes later and wins) so that a draw the verb
#: accepts does a small amount of work: ``design`` needs no input file to run.
CHEAP = {"design": ["--budget", "3", "--random", "1", "--hours", "1"]}


def _pool(root: Path) -> list[str]:
    """Paths a user can get wrong; none of them can be written to or read as good data."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "folder.mcap").mkdir(exist_ok=True)
    (root / "empty.toml").write_bytes(b"")
    (root / "latin1.toml").write_bytes(b"\xff\xfe[unit]\nname = 'x'\n")
    (root / "garbage.mcap").write_bytes(b"\x89MCAP0\r\n" + os.urandom(64))
    (root / "garbage.csv").write_text("a,b\n1,2,3\n\x00\n")
    (root / "params.toml").write_text("[parameters.mult_D]\nvalue = 1e400\n")
    (root / "map.toml").write_text("[scans]\nnothing = 1\n")
    return [str(root / n) for n in ("folder.mcap", "empty.toml", "latin1.toml",
                                    "garbage.mcap", "garbage.csv", "params.toml", "map.toml")
            ] + [str(root / "missing" / "x.mcap"), "/proc/1/nope", "-", ""]


def _value(action, pool: list[str]) -> st.SearchStrategy[str]:
    if action.choices:
        return st.sampled_from([*map(str, action.choices), "bogus"])
    if action.type is float:
        return st.sampled_from(FLOATS)
    if action.type is int:
        return st.sampled_from(INTS)
    return st.one_of(st.sampled_from(pool), st.text(min_size=1, max_size=12).filter(
        lambda s: not s.startswith("-")))


@st.composite
def command_lines(draw, verb: str, pool: list[str]) -> list[str]:
    parser = build_parser()._subparsers._group_actions[0].choices[verb]  # type: ignore
    argv = [verb, *CHEAP.get(verb, [])]
    for action in parser._actions:
        if not action.option_strings:
            argv += [draw(_value(action, pool)) for _ in range(1 if action.nargs is None
                                                               else draw(st.integers(1, 2)))]
        elif action.option_strings[0] not in ("-h", "--help") and draw(st.booleans()):
            if action.nargs == 0:
                argv.append(action.option_strings[0])
            else:
                argv += [action.option_strings[0], draw(_value(action, pool))]
    if verb == "health" and "--timeout" not in argv:
        argv += ["--timeout", "0.5"]
    return argv


def _run(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own errors
            code = exc.code if isinstance(exc.code, int) else 2
    return int(code), err.getvalue()


def _check(argv: list[str], code: int, err: str) -> None:
    assert "Traceback" not in err, (argv, err[-2000:])
    assert "unexpected" not in err, (argv, err[-500:])
    if code != 0:
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert lines and lines[-1].startswith("softsensor"), (argv, err[-500:])


@pytest.fixture
def no_daemon(monkeypatch):
    """``softsensor run`` stops where the daemon would start serving."""
    from softsensor.service.daemon import Daemon

    async def _return(self, stop, ready=None):  # noqa: ANN001
        return None

    monkeypatch.setattr(Daemon, "run", _return)


def _fuzz(verb: str, tmp_path_factory, examples: int, derandomize: bool) -> None:
    pool = _pool(tmp_path_factory.mktemp("pool"))
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))  # whatever a verb writes by default lands here
    try:
        @settings(max_examples=examples, derandomize=derandomize, deadline=None,
                  database=None, suppress_health_check=list(HealthCheck))
        @given(command_lines(verb, pool))
        def check(argv: list[str]) -> None:
            _check(argv, *_run(argv))

        check()
    finally:
        os.chdir(cwd)


@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_answers_bad_input_with_one_line(verb: str, tmp_path_factory, no_daemon):
    _fuzz(verb, tmp_path_factory, 25, derandomize=True)


@pytest.mark.slow
@pytest.mark.parametrize("verb", VERBS)
def test_every_verb_answers_fresh_bad_input_with_one_line(verb: str, tmp_path_factory,
                                                          no_daemon):
    _fuzz(verb, tmp_path_factory, 300, derandomize=False)


PLANT_SERVER_BAD = [
    ["plant-server", "--port", "99999"],
    ["plant-server", "--port", "-1"],
    ["plant-server", "--speed", "nan"],
    ["plant-server", "--speed", "0"],
    ["plant-server", "--seed", "-1"],
    ["plant-server", "--hours", "inf"],
    ["plant-server", "--config", "/nonexistent.toml"],
]


@pytest.mark.parametrize("argv", PLANT_SERVER_BAD, ids=lambda a: " ".join(a[1:]))
def test_plant_server_refuses_bad_options_in_one_line(argv: list[str]):
    code, err = _run(argv)
    assert code == 2, err
    _check(argv, code, err)


def test_a_bad_lab_dir_and_a_busy_port_are_one_line(tmp_path: Path):
    import socket

    f = tmp_path / "file"
    f.write_text("x")
    code, err = _run(["plant-server", "--lab-dir", str(f), "--hours", "0.5", "--port", "0"])
    assert code == 2 and "not a folder" in err, err
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        code, err = _run(["plant-server", "--hours", "0.5", "--port", str(s.getsockname()[1]),
                          "--once"])
    assert code == 2, err
    _check([], code, err)
