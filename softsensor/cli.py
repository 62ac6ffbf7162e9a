"""The ``softsensor`` command: wires configuration, sources, estimators and sinks together.

Verbs (CONTRACT section 4 and the project's own): ``simulate``, ``calibrate``, ``identify``,
``validate``, ``replay``, ``run``, ``plant-server``, ``diagnose``. Each verb lives in the
package that owns it; this module only parses arguments and turns every
:class:`~softsensor.errors.SoftsensorError` into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Callable, Sequence

from softsensor import __version__
from softsensor.errors import SoftsensorError

log = logging.getLogger("softsensor")


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line (``softsensor: error: ...``) with exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def _simulate(args: argparse.Namespace) -> int:
    from softsensor.plant.commands import load_plant, simulate_plant

    cfg = load_plant(args)
    day = simulate_plant(cfg, args)
    day.write(args.out)
    eff = day.effect
    what = "clean day" if eff["effect"] == "none" else (
        f"effect {eff['effect']} magnitude {eff['magnitude']:g} {eff['unit']}"
        + (f" on {eff['channel']}" if eff.get("channel") else ""))
    plant = ("plant independent, plant seed " + str(args.plant_seed)
             if args.plant == "independent" else "plant model")
    print(f"wrote {args.out}: {len(day.scans)} scans over {args.hours:g} h, "
          f"{len(day.labs)} lab results, {what}, seed {args.seed}, {plant}")
    return 0


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    from softsensor.plant.commands import add_plant_options
    from softsensor.plant.effects import EFFECTS

    p = sub.add_parser("simulate", help="run a virtual plant and record a day as MCAP")
    p.add_argument("--hours", type=float, default=48.0, help="length of the record [h]")
    p.add_argument("--seed", type=int, default=0, help="seed of every random stream of the day")
    p.add_argument("--effect", default=None, metavar="CAUSE",
                   help=f"hide one effect in the day: {', '.join(EFFECTS)}")
    p.add_argument("--magnitude", type=float, default=None,
                   help="size of the effect (units and ranges: softsensor.plant.effects)")
    add_plant_options(p)
    p.add_argument("--config", default=None, help="plant config (default: built-in dryer1)")
    p.add_argument("--out", required=True, help="MCAP file to write")
    p.set_defaults(func=_simulate)


#: Verbs provided by other packages: (module, function adding the sub-parser).
_PLUGGED: tuple[tuple[str, str], ...] = (
    ("softsensor.plant.commands", "add_commands"),
    ("softsensor.calibration.commands", "add_commands"),
    ("softsensor.service.commands", "add_commands"),
    ("softsensor.diagnosis.commands", "add_commands"),
    ("softsensor.historian_commands", "add_commands"),
)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="softsensor", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"softsensor {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    _add_simulate(sub)
    for module, func in _PLUGGED:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        add: Callable[[argparse._SubParsersAction], None] = getattr(mod, func)
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    try:
        return int(args.func(args) or 0)
    except SoftsensorError as exc:
        print(f"softsensor: {exc}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:
        print(f"softsensor: {exc.filename}: no such file", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("softsensor: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
