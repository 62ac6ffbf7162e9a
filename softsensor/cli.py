"""The ``softsensor`` command: wires configuration, sources, estimators and sinks together.

Verbs (CONTRACT section 4 and the project's own): ``simulate``, ``calibrate``, ``identify``,
``validate``, ``replay``, ``run``, ``plant-server``, ``diagnose``, ``learn-normal``,
``import``, ``export``, ``design``, ``advise``.
Each verb lives in a module of :mod:`softsensor.apps` (:data:`VERBS`); a command line
naming its verb imports that verb's module alone, any other (``--help``) all of them. A
module that fails to import stops the command with one line naming it (exit status 1)
rather than hiding its verbs. This module only parses arguments and turns every
:class:`~softsensor.errors.SoftsensorError` into one line on stderr and exit status 2 (1 for a
package of an extra that is not installed). What every verb's ``--help`` shares is set here,
in one place: its description (the verb's one-line help where the module gives none), its
exit statuses (:data:`EXIT_CODES`, the README's table), ``-v``/``--verbose`` after the verb
too, and one metavar per shared option (:data:`METAVARS`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import math
import signal
import sys
import textwrap
import threading
import traceback
from collections.abc import Callable, Sequence

from softsensor import __version__
from softsensor.errors import MissingPackageError, SoftsensorError, one_line


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (``softsensor: error: ...``) with exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, one_line(f"{self.prog}: error: {message}") + "\n")


#: Modules of :mod:`softsensor.apps` that add verbs, each through its ``add_commands``, and
#: the verbs each adds (``tests/test_cli.py`` checks these against what they add). A command
#: line naming a verb imports that verb's module only: the daemon (``run``) must not carry
#: the calibration's, the plant's and the import's libraries (150 MB resident, issue 31).
VERBS: dict[str, tuple[str, ...]] = {
    "softsensor.apps.virtual_plant": ("simulate", "plant-server"),
    "softsensor.apps.calibrate": ("calibrate", "identify"),
    "softsensor.apps.validate": ("validate",),
    "softsensor.apps.streaming": ("run", "replay", "health"),
    "softsensor.apps.diagnose": ("diagnose", "learn-normal"),
    "softsensor.apps.import_export": ("import", "export"),
    "softsensor.apps.design": ("design",),
    "softsensor.apps.advise": ("advise",),
}


#: What each verb's exit statuses mean (the README's "Exit codes" table, which a test holds
#: this against); shown at the end of the verb's ``--help``.
_BAD_INPUT = ("bad input: a missing or unreadable file, a corrupt MCAP, an unknown signal or "
              "effect, a malformed config or option")
_BUG = ("a bug (one line; -v shows the traceback), a module that cannot be imported, or a "
        "package of the offline extra that is not installed")
EXIT_CODES: dict[str, dict[int, str]] = {
    **{verb: {0: "done", 1: _BUG, 2: _BAD_INPUT, 130: "interrupted, Ctrl-C or SIGTERM"}
       for verb in ("simulate", "import", "export", "identify", "validate", "diagnose",
                    "learn-normal", "design", "advise")},
    "calibrate": {0: "wrote --out: the calibrated parameters, or the current ones kept with "
                     "the model error learned when the calibrated predict the held-out data "
                     "worse; the last line says which and to deploy it",
                  1: _BUG, 2: _BAD_INPUT + "; a day too short or without the lab results a "
                                           "window needs",
                  130: "interrupted, Ctrl-C or SIGTERM"},
    "replay": {0: "done (a warning on stderr when most windows were stale)", 1: _BUG,
               2: _BAD_INPUT + "; nothing estimated from data (every window stale, the line "
                               "says why)",
               130: "interrupted, Ctrl-C or SIGTERM (the partial --out removed)"},
    "run": {0: "stopped by SIGTERM or SIGINT", 1: _BUG,
            2: _BAD_INPUT + "; a port that cannot be used (one line naming the [outputs.*] "
                            "table); a checkpoint refused with --resume required"},
    "plant-server": {0: "stopped by SIGTERM or SIGINT, or --once served its day", 1: _BUG,
                     2: _BAD_INPUT + "; a port that cannot be used (checked before the day "
                                     "is simulated)"},
    "health": {0: "the daemon answered and its estimator is not stalled (its status, ok or "
                  "degraded, in the line)",
               1: "no answer, refused, or the estimator stalled (the container's HEALTHCHECK)",
               2: _BAD_INPUT, 130: "interrupted, Ctrl-C or SIGTERM"},
}
#: One metavar per option that several verbs share (a file's kind in its name).
METAVARS: dict[str, str] = {"--params": "PARAMS.toml", "--config": "PLANT.toml",
                            "--tagmap": "TAGMAP.toml", "--lab-dir": "DIR",
                            "--data-dir": "DIR", "--checkpoint": "FILE"}


class _Formatter(argparse.HelpFormatter):
    """argparse's own layout, except the exit statuses, laid out already (:func:`_epilog`)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if text.startswith(_EPILOG_HEAD):
            return text
        return super()._fill_text(text, width, indent)


_EPILOG_HEAD = "exit status:"


def _epilog(verb: str) -> str:
    """The exit statuses of ``verb``, wrapped to 79 columns under their codes."""
    lines = [_EPILOG_HEAD]
    for code, text in EXIT_CODES.get(verb, {}).items():
        lines += textwrap.wrap(text, 79, initial_indent=f"  {code:<4} ",
                               subsequent_indent=" " * 7)
    return "\n".join(lines)


def _shared_help(sub: argparse._SubParsersAction) -> None:
    """What every verb's ``--help`` shares (module docstring)."""
    for choice in sub._choices_actions:
        verb = sub.choices[choice.dest]
        if not verb.description and choice.help:
            verb.description = choice.help[0].upper() + choice.help[1:] + "."
        verb.epilog = _epilog(choice.dest)
        verb.formatter_class = _Formatter
        for action in verb._actions:
            for flag in action.option_strings:
                if flag in METAVARS and action.metavar is None:
                    action.metavar = METAVARS[flag]
        # after the verb too (softsensor run -v): the default stays the one before it
        verb.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                          help="debug logging, and the traceback of an unexpected error")


class VerbImportError(Exception):
    """A verb module failed to import: a broken install or a bug, never to be hidden by
    dropping its verbs from the command line."""


def _import_verbs(module: str) -> Callable[[argparse._SubParsersAction], None]:
    try:
        return importlib.import_module(module).add_commands
    except ImportError as exc:
        raise VerbImportError(f"cannot load the verbs of {module}: {exc}") from exc


def _module_of(argv: Sequence[str]) -> str | None:
    """The verb module of the command line's verb (its first word that is not an option), or
    None (no verb, an unknown one, or help asked for the whole command)."""
    for word in argv:
        if word in ("-h", "--help", "--version"):
            return None
        if not word.startswith("-"):
            return next((m for m, verbs in VERBS.items() if word in verbs), None)
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The command line's parser: with every verb, or (``argv`` naming a verb) with the verbs
    of that verb's module only."""
    parser = _Parser(prog="softsensor", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"softsensor {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="debug logging, and the traceback of an unexpected error")
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    only = None if argv is None else _module_of(argv)
    for module in tuple(VERBS) if only is None else (only,):
        _import_verbs(module)(sub)
    _shared_help(sub)
    return parser


def check_numbers(args: argparse.Namespace) -> str | None:
    """The rules every verb's options share: no NaN or infinity, seeds that numpy takes
    (0 .. 2**32 - 1), TCP ports (0 .. 65535), no NUL in a text; the message names the
    option."""
    for key, value in vars(args).items():
        flag = "--" + key.replace("_", "-")
        texts = value if isinstance(value, list) else [value]
        if any(isinstance(t, str) and "\x00" in t for t in texts):
            return f"argument {flag}: contains a NUL character, which no path or name may"
        if isinstance(value, float) and not math.isfinite(value):
            return f"argument {flag}: must be a finite number, got {value}"
        if isinstance(value, bool) or not isinstance(value, int):
            continue
        if "seed" in key and not 0 <= value < 2**32:
            return f"argument {flag}: must be in 0..{2**32 - 1}, got {value}"
        if key == "port" and not 0 <= value <= 65535:
            return f"argument {flag}: must be a TCP port in 0..65535, got {value}"
    return None


def setup_logging(verbose: bool = False) -> None:
    """The project's loggers (``softsensor.*``) at INFO, every library's at WARNING (asyncua
    alone logs about a thousand INFO lines while its server starts; pymodbus, numba and
    matplotlib add more); ``--verbose`` shows everything at DEBUG."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    logging.getLogger("softsensor").setLevel(logging.DEBUG if verbose else logging.INFO)


def _interrupted(_signum: int, _frame: object) -> None:
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser(argv)
    except VerbImportError as exc:
        print(f"softsensor: {exc}", file=sys.stderr)
        return 1
    args = parser.parse_args(argv)
    problem = check_numbers(args)
    if problem is not None:
        print(one_line(f"softsensor {args.verb}: error: {problem}"), file=sys.stderr)
        return 2
    setup_logging(args.verbose)
    # one rule for every verb: SIGTERM ends it as Ctrl-C does (its cleanup, one line, 130);
    # the daemons (run, plant-server) put their own handlers in place of this one
    with _sigterm_as_interrupt():
        return _run_verb(args)


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt while the verb runs (the handler before is put back
    after: ``main`` is also called inside other programs and tests)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGTERM, _interrupted)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


def _run_verb(args: argparse.Namespace) -> int:
    """Run the verb; every way it ends as an exit status and at most one line."""
    try:
        return int(args.func(args) or 0)
    except MissingPackageError as exc:  # the install, not the input: as a broken one
        print(one_line(f"softsensor: {exc}"), file=sys.stderr)
        return 1
    except SoftsensorError as exc:
        print(one_line(f"softsensor: {exc}"), file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(one_line(f"softsensor: {exc.filename}: no such file"), file=sys.stderr)
        return 2
    except OSError as exc:  # a path given that cannot be used: a folder, no permission
        where = f"{exc.filename}: " if exc.filename else ""
        print(one_line(f"softsensor: {where}{exc.strerror or exc}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("softsensor: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # noqa: BLE001 - a bug: one line, the traceback with -v
        if args.verbose:
            # printed, not logged: a verb may have put its own one-line formatter on the
            # handlers (run's key=value lines), which would keep only the exception's name
            traceback.print_exc(file=sys.stderr)
        first = str(exc).splitlines()[0][:300] if str(exc) else ""
        print(one_line(f"softsensor {args.verb}: unexpected {type(exc).__name__}: {first} "
                       f"(this is a bug; --verbose shows where)"), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
