"""The command line registers every verb module, and a module that fails to import stops it
with one line naming the module instead of silently dropping its verbs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

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
