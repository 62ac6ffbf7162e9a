"""The ``softsensor`` command: wires configuration, sources, estimators and sinks together.

Verbs (CONTRACT section 4 and the project's own): ``simulate``, ``calibrate``, ``identify``,
``validate``, ``replay``, ``run``, ``plant-server``, ``diagnose``, ``import``, ``export``,
``design``.
Each verb lives in a module of :mod:`softsensor.apps` (:data:`VERBS`); a module that
fails to import stops the command with one line naming it (exit status 1) rather than hiding
its verbs. This module only parses arguments and turns every
:class:`~softsensor.errors.SoftsensorError` into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import math
import sys
from collections.abc import Callable, Sequence

from softsensor import __version__
from softsensor.errors import SoftsensorError, one_line

log = logging.getLogger("softsensor")


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
    "softsensor.apps.calibrate": ("calibrate", "identify", "validate"),
    "softsensor.apps.streaming": ("run", "replay", "health"),
    "softsensor.apps.diagnose": ("diagnose",),
    "softsensor.apps.historian": ("import", "export"),
    "softsensor.apps.design": ("design",),
}


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
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    only = None if argv is None else _module_of(argv)
    for module in tuple(VERBS) if only is None else (only,):
        _import_verbs(module)(sub)
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
    try:
        return int(args.func(args) or 0)
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
        log.debug("unexpected error", exc_info=True)
        first = str(exc).splitlines()[0][:300] if str(exc) else ""
        print(one_line(f"softsensor {args.verb}: unexpected {type(exc).__name__}: {first} "
                       f"(this is a bug; --verbose shows where)"), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
