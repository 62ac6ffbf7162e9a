"""The command line (``softsensor/cli.py``): it registers every verb module, and a module that
fails to import stops it with one line naming the module instead of silently dropping its
verbs; a verb imports its own module only; every verb describes itself, lists its exit codes
(the commands page's table, ``docs/user-guide/commands.md``) and helps every option; ``-v`` prints
the traceback it promises; library
loggers stay quiet unless asked (issues 24 and 30)."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest
from paths import REPO

from softsensor import cli

CONTRACT_VERBS = {"simulate", "calibrate", "replay", "diagnose"}


def test_every_verb_module_registers_its_verbs() -> None:
    parser = cli.build_parser()
    verbs = set(parser._subparsers._group_actions[0].choices)  # the one sub-parser group
    assert CONTRACT_VERBS <= verbs
    assert {"identify", "validate", "run", "plant-server"} <= verbs
    # the table a command line's verb is looked up in names each verb's own module
    assert {v for vs in cli.VERBS.values() for v in vs} == verbs


@pytest.mark.parametrize(("module", "missing"), [
    ("broken_verbs", "softsensor_no_such_dependency"),  # a dependency of the module is absent
    ("softsensor.apps.no_such_verbs", "softsensor.apps.no_such_verbs"),  # the module itself
])
def test_a_verb_module_that_fails_to_import_is_named(module: str, missing: str, tmp_path: Path,
                                                     monkeypatch, capsys) -> None:
    (tmp_path / "broken_verbs.py").write_text("import softsensor_no_such_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "broken_verbs", raising=False)
    monkeypatch.setattr(cli, "VERBS", {"softsensor.apps.virtual_plant": ("simulate",),
                                       module: ("broken-verb",)})
    with pytest.raises(cli.VerbImportError, match=module):
        cli.build_parser()
    # its own verb, and a command line that needs every verb (help, an unknown verb), stop
    # with one line naming the module
    for argv in (["broken-verb"], ["no-such-verb"], ["--help"]):
        assert cli.main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1
        assert module in err[0] and missing in err[0]


def test_a_verb_imports_its_own_module_only() -> None:
    """``softsensor run`` does not import the calibration's, the plant's or the import's
    modules (and pandas with them: 150 MB of the daemon's resident memory, issue 31)."""
    for module, verbs in cli.VERBS.items():  # the table says what each module adds
        parser = cli.build_parser([verbs[0]])
        assert set(parser._subparsers._group_actions[0].choices) == set(verbs), module
    code = ("import sys; from softsensor import cli; cli.build_parser(['-v', 'run']); "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            f"('pandas', 'scipy', 'numba') or m in {sorted(cli.VERBS)!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "['softsensor.apps.streaming']", out


_OPCUA_START = """
import asyncio, logging, socket, sys
from softsensor.cli import setup_logging
setup_logging(verbose=sys.argv[1] == "verbose")
from softsensor.presentation.display import DisplaySettings
from softsensor.outputs.opcua_server import EstimateOpcUaServer
from softsensor.outputs.settings import OpcUaSettings
with socket.socket() as s:
    s.bind(("127.0.0.1", 0)); port = s.getsockname()[1]
async def main():
    server = EstimateOpcUaServer(OpcUaSettings(enabled=True, port=port), DisplaySettings())
    await server.start()
    await server.stop()
asyncio.run(main())
logging.getLogger("softsensor.test").info("done")
"""


@pytest.mark.parametrize("mode", ["quiet", "verbose"])
def test_library_loggers_are_quiet_unless_asked(mode):
    """An OPC UA server start logged about a thousand asyncua INFO lines into the daemon's
    log; the project's own INFO lines stay."""
    r = subprocess.run([sys.executable, "-c", _OPCUA_START, mode], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stderr.splitlines()
    library = [ln for ln in lines if " asyncua" in ln and (" INFO " in ln or " DEBUG " in ln)]
    assert any("softsensor.test: done" in ln for ln in lines), r.stderr[-2000:]
    if mode == "quiet":
        assert library == [], library[:5]
    else:
        assert len(library) > 20


def test_verbose_before_or_after_the_verb_prints_the_traceback(tmp_path, capsys, monkeypatch):
    """An unexpected error says "--verbose shows where": with ``-v`` before or after the verb
    the traceback is printed, also under ``run``, whose key=value log lines kept only the
    exception's name."""
    from softsensor.cli import main
    from softsensor.service.daemon import Daemon

    async def broken(self, stop, ready=None):
        raise ValueError("a bug deep inside")

    monkeypatch.setattr(Daemon, "run", broken)
    base = ["--no-record", "--lab-dir", str(tmp_path / "lab"), "--checkpoint",
            str(tmp_path / "ckpt.json")]
    for argv in (["run", *base], ["-v", "run", *base], ["run", "-v", *base],
                 ["run", *base, "--verbose"]):
        capsys.readouterr()
        assert main(argv) == 1, argv
        err = capsys.readouterr().err
        assert err.rstrip("\n").splitlines()[-1] == (
            "softsensor run: unexpected ValueError: a bug deep inside (this is a bug; "
            "--verbose shows where)"), err
        shown = "Traceback (most recent call last)" in err and "in broken" in err
        assert shown == (argv != ["run", *base]), (argv, err)


def _verbs() -> dict[str, argparse.ArgumentParser]:
    from softsensor.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _readme_exit_codes() -> dict[str, set[int]]:
    """Per verb, the exit statuses the documented table gives (docs/user-guide/commands.md;
    a '-' cell: none)."""
    text = (REPO / "docs" / "user-guide" / "commands.md").read_text()
    table = text.split("| verb | 0 | 1 | 2 | 130 |")[1].split("\n\n")[0]
    out: dict[str, set[int]] = {}
    for row in table.strip().splitlines()[1:]:
        cells = [c.strip() for c in row.strip("|").split("|")]
        codes = {code for code, cell in zip((0, 1, 2, 130), cells[1:], strict=True)
                 if cell != "-"}
        for verb in re.findall(r"`([a-z-]+)`", cells[0]):
            out[verb] = codes
    return out


def test_every_verb_describes_itself_lists_its_exit_codes_and_helps_every_option(capsys):
    """10 of 12 verbs had no description in --help, none listed its exit codes, four options
    had no help, --params showed as PARAMS.toml and PARAMS, and --fit-fraction named an
    internal constant."""
    from softsensor.cli import EXIT_CODES, main

    readme = _readme_exit_codes()
    verbs = _verbs()
    assert set(verbs) == set(readme) == set(EXIT_CODES)
    metavars: dict[str, set[str]] = {}
    for name, verb in verbs.items():
        assert verb.description and verb.description[0].isupper(), name
        assert set(EXIT_CODES[name]) == readme[name], name
        for action in verb._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and "DEFAULT_" not in action.help, (name, action.dest)
            for flag in action.option_strings:
                if action.nargs != 0:
                    metavars.setdefault(flag, set()).add(str(action.metavar or action.dest))
        with pytest.raises(SystemExit) as done:
            main([name, "--help"])
        assert done.value.code == 0
        shown = capsys.readouterr().out
        assert "exit status:" in shown, name
        for code in EXIT_CODES[name]:
            assert re.search(rf"^  {code}\s+\S", shown, re.M), (name, code)
    for flag in ("--params", "--config"):
        assert len(metavars[flag]) == 1, (flag, metavars[flag])
    assert metavars["--params"] == {"PARAMS.toml"}


def test_long_verbs_take_quiet_and_design_speaks_plant_units():
    verbs = _verbs()
    for name in ("calibrate", "diagnose", "replay", "design", "plant-server"):
        assert any("--quiet" in a.option_strings for a in verbs[name]._actions), name
    design = {a.dest: a.help for a in verbs["design"]._actions}
    assert "[°C]" in design["T_sp_band"] and "[t/h]" in design["m_air_band"]
    assert "[t/h per min]" in design["m_air_rate"]


def test_a_missing_offline_package_exits_1_as_the_readme_says(tmp_path, capsys, monkeypatch):
    import importlib.util

    from softsensor.cli import main

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "optuna" else real(name, *a))
    assert main(["validate", str(tmp_path / "day.mcap"), "--params",
                 str(tmp_path / "p.toml")]) == 1
    err = capsys.readouterr().err
    assert err == ("softsensor: validate needs the package optuna, which this install leaves "
                   "out: pip install 'softsensor[offline]'\n")


def test_health_imports_only_its_own_verbs():
    """``softsensor health`` took 2.9 to 5.8 s here against a daemon that answered at once:
    building the parser imported every verb module, the calibration's SciPy among them. A
    command line naming its verb imports that verb's module alone."""
    code = ("import sys; from softsensor.cli import build_parser; "
            "p = build_parser(['health']); "
            "print('scipy.stats' in sys.modules, 'softsensor.apps.calibrate' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120)
    scipy, calibrate = r.stdout.split()
    # what it imports, not how long it took: the time depends on the machine's load (issue 49)
    assert (scipy, calibrate) == ("False", "False"), r.stdout
