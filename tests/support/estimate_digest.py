"""A SHA-256 of the demo day's estimates: a refactoring of the service must leave them as they are.

``softsensor replay replay/demo-day.mcap`` streams the recorded demo day (48 h, 16 lab
results) through the estimator service (in memory; ``--via-zenoh`` over Zenoh, the same
digest); :func:`digest` hashes every number of every
``/softsensor/estimate`` body it records, in order: each body's numeric leaves (nested tables
flattened to dotted keys; ``null`` kept, since a number that became null is a change), each as
its exact bits (``float.hex``), under the message's log time. Text (``detail``, ``notes``) and
flags are left out: they follow from the numbers, and their wording may be improved.

``tests/fixtures/demo_estimates_digest.json`` holds the digest and every number it hashes
(the 289 estimates' log times and 35 numeric leaves each, to 12 digits);
``tests/service/test_offline_replay.py`` requires the in-memory and the Zenoh replays of one
run to give the same digest (bit for bit: the transport must not move a bit) and each to
match the stored numbers at the tolerance of :mod:`stored_numbers` (1e-9 relative): numba
compiles for the host CPU and the system's ``libm``, so another machine differs in the last
bits (2.3e-14 relative, issue 49) while the estimator is the same. When the estimator changes
*on purpose* (its estimates are meant to move), regenerate the file and commit it with the
change, saying why the numbers moved::

    .venv/bin/python tests/support/estimate_digest.py --write

``python tests/support/estimate_digest.py`` replays the demo, prints the digest, whether it
matches the stored one bit for bit, and whether the numbers match within the tolerance.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from paths import FIXTURES, REPLAY, REPO

DEMO = REPLAY / "demo-day.mcap"
STORED = FIXTURES / "demo_estimates_digest.json"



def replay_demo(out: Path, *options: str) -> str:
    """Run ``softsensor replay`` on the demo day into ``out`` (with ``options``, e.g.
    ``--via-zenoh``); its summary line (stderr)."""
    from softsensor.cli import main as cli_main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = cli_main(["replay", str(DEMO), "--out", str(out), "--quiet", *options])
    if rc != 0:
        raise RuntimeError(f"replay of the demo day failed: {err.getvalue()}")
    return err.getvalue()


def estimates(path: Path) -> list[tuple[int, dict[str, Any]]]:
    """The ``/softsensor/estimate`` messages of a replay's output, in log-time order."""
    from softsensor.recording.mcap_day import iter_messages
    from softsensor.signals import TOPIC_ESTIMATE

    return [(t, body) for _, t, body in iter_messages(path, topics=[TOPIC_ESTIMATE])]


def _leaves(prefix: str, value: Any) -> Iterator[str]:
    """``key=bits`` of every number (and null) under ``value``, keys sorted."""
    if isinstance(value, dict):
        for key in sorted(value):
            yield from _leaves(f"{prefix}.{key}" if prefix else str(key), value[key])
    elif value is None:
        yield f"{prefix}=null"
    elif isinstance(value, float):
        yield f"{prefix}={value.hex()}"
    elif isinstance(value, int) and not isinstance(value, bool):
        yield f"{prefix}={value}"


def digest(messages: list[tuple[int, dict[str, Any]]]) -> str:
    """SHA-256 over each estimate's log time and numeric leaves (module docstring)."""
    h = hashlib.sha256()
    for t, body in messages:
        h.update(f"@{t}\n".encode())
        for line in _leaves("", body):
            h.update(f"{line}\n".encode())
    return h.hexdigest()


def _leaf_values(prefix: str, value: Any) -> Iterator[tuple[str, float | int | None]]:
    """``(key, number)`` of every leaf :func:`_leaves` hashes, in the same order."""
    if isinstance(value, dict):
        for key in sorted(value):
            yield from _leaf_values(f"{prefix}.{key}" if prefix else str(key), value[key])
    elif value is None or isinstance(value, (float, int)) and not isinstance(value, bool):
        yield prefix, value


def numbers(messages: list[tuple[int, dict[str, Any]]]) -> dict[str, list[float | int | None]]:
    """Every number the digest hashes, by field: ``@log_time`` [ns] and each numeric leaf's
    values over the estimates (``null`` where an estimate has it null; a leaf some estimates
    lack makes the field shorter, which the comparison reports)."""
    out: dict[str, list[float | int | None]] = {"@log_time": [t for t, _ in messages]}
    for _, body in messages:
        for key, v in _leaf_values("", body):
            out.setdefault(key, []).append(v)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true",
                   help=f"store the digest in {STORED.relative_to(REPO)} (the estimator changed "
                        "on purpose)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "estimates.mcap"
        replay_demo(out)
        messages = estimates(out)
    from model_digest import store_or_compare  # this folder, as for the script's own run

    return store_or_compare(digest(messages), numbers(messages), STORED, args.write)


if __name__ == "__main__":
    sys.exit(main())
