"""The command line's reference, rendered from the parsers themselves.

``.. softsensor-cli::`` builds :func:`softsensor.cli.build_parser` (every verb) and writes, per
verb in the parser's order: its description, its usage line as argparse prints it, a table of
its arguments (flags, metavar, default, help) and its exit statuses
(:data:`softsensor.cli.EXIT_CODES`). Nothing is copied by hand, so a renamed option or a verb
added shows here at the next build. (sphinx-argparse would do the same for plain parsers, but
softsensor's verbs get their description, metavars, ``-v`` and exit statuses added after they
are built, by ``softsensor.cli._shared_help``; reading the finished parser renders them as
``--help`` shows them.)
"""

from __future__ import annotations

import argparse

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles


def _literal(text: str) -> str:
    """``text`` as reST inline literal (argparse metavars hold ``|``, ``*``, ``[``)."""
    return "``" + text.replace("`", "'") + "``" if text else ""


def _cell(text: str) -> str:
    """One line of a list-table cell: reST-safe plain text."""
    return " ".join(text.split()).replace("*", r"\*").replace("|", r"\|")


def _default(action: argparse.Action) -> str:
    if action.default in (None, argparse.SUPPRESS, False) or action.nargs == 0:
        return ""
    if isinstance(action.default, list | tuple):
        return _literal(" ".join(map(str, action.default)))
    return _literal(str(action.default))


def _flags(action: argparse.Action, parser: argparse.ArgumentParser) -> str:
    if not action.option_strings:
        return _literal(parser._get_formatter()._format_args(action, action.dest))
    fmt = parser._get_formatter()
    if action.nargs == 0:
        return ", ".join(_literal(f) for f in action.option_strings)
    args = fmt._format_args(action, action.dest.upper())
    return ", ".join(_literal(f"{f} {args}") for f in action.option_strings)


def _help(action: argparse.Action) -> str:
    text = action.help or ""
    if "%(" in text:
        params = dict(vars(action), prog="softsensor")
        text = text % {k: v for k, v in params.items() if isinstance(k, str)}
    return _cell(text)


def verb_rst(name: str, parser: argparse.ArgumentParser, exit_codes: dict[int, str]
             ) -> list[str]:
    """reST lines for one verb: description, usage, arguments, exit statuses."""
    lines = [f".. _cli-{name}:", "", f"``softsensor {name}``", "-" * (len(name) + 15), ""]
    if parser.description:
        lines += [_cell(parser.description), ""]
    usage = parser.format_usage().removeprefix("usage: ").strip()
    lines += [".. code-block:: text", ""]
    lines += ["   " + ln for ln in usage.splitlines()] + [""]
    actions = [a for a in parser._actions if not isinstance(a, argparse._HelpAction)]
    if actions:
        lines += [".. list-table::", "   :header-rows: 1", "   :widths: 30 15 55", "",
                  "   * - argument", "     - default", "     - what it does"]
        for action in actions:
            lines += [f"   * - {_flags(action, parser)}", f"     - {_default(action)}",
                      f"     - {_help(action)}"]
        lines.append("")
    if exit_codes:
        lines += ["Exit statuses:", ""]
        lines += [f"- ``{code}``: {_cell(text)}" for code, text in exit_codes.items()]
        lines.append("")
    return lines


def cli_rst() -> list[str]:
    """reST of the whole command line: the command's own options, then every verb."""
    from softsensor.cli import EXIT_CODES, build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    lines = [".. code-block:: text", ""]
    lines += ["   " + ln for ln in parser.format_usage().removeprefix("usage: ").splitlines()]
    lines.append("")
    for name, verb in sub.choices.items():
        lines += verb_rst(name, verb, EXIT_CODES.get(name, {}))
    return lines


class CliReference(SphinxDirective):
    """``.. softsensor-cli::``: every verb of ``softsensor``, from its parser."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        import softsensor.cli

        self.env.note_dependency(softsensor.cli.__file__)
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(cli_rst(), source="softsensor.cli"),
                                 node)
        return node.children


def setup(app):
    app.add_directive("softsensor-cli", CliReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
