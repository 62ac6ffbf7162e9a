"""The command line's reference (``docs/_ext/cli_reference.py``) is the parsers' own: every
verb, every option string and every exit status, as ``softsensor VERB --help`` shows them."""

from __future__ import annotations

import argparse
import re

from paths import REPO

from softsensor.cli import EXIT_CODES, build_parser


def test_every_verb_option_and_exit_status_is_rendered(cli_reference):
    rst = "\n".join(cli_reference.cli_rst())
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(EXIT_CODES)
    for name, verb in sub.choices.items():
        start = rst.index(f"``softsensor {name}``\n")
        end = rst.find("\n.. _cli-", start)
        section = rst[start:end if end >= 0 else None]
        for action in verb._actions:
            if isinstance(action, argparse._HelpAction):
                continue  # --help is every verb's, and says nothing of the verb
            for flag in action.option_strings:
                assert f"``{flag}" in section, (name, flag)
        for code in EXIT_CODES[name]:
            assert f"- ``{code}``:" in section, (name, code)
        # the usage line as argparse prints it (its words, however the page indents them)
        usage = " ".join(verb.format_usage().removeprefix("usage: ").split())
        assert usage in " ".join(section.split()), (name, usage)


def test_the_cli_page_renders_the_reference():
    page = (REPO / "docs" / "reference" / "cli.rst").read_text(encoding="utf-8")
    assert re.search(r"^\.\. softsensor-cli::$", page, re.M), page
