"""A SHA-256 of the demo day's estimates: a refactoring of the service must leave them as they are.

``softsensor replay replay/demo-day.mcap`` streams the recorded demo day (48 h, 16 lab
results) through the estimator service (in memory; ``--via-zenoh`` over Zenoh, the same
digest); :func:`digest` hashes every number of every
``/softsensor/estimate`` body it records, in order: each body's numeric leaves (nested tables
flattened to dotted keys; ``null`` kept, since a number that became null is a change), each as
its exact bits (``float.hex``), under the message's log time. Text (``detail``, ``notes``) and
flags are left out: they follow from the numbers, and their wording may be improved.

``tests/service/test_offline_replay.py`` compares it with
``tests/fixtures/demo_estimates_digest.json``. When the estimator changes *on purpose* (its
estimates are meant to move), regenerate the file and commit it with the change, saying why the
numbers moved::

    .venv/bin/python tests/support/estimate_digest.py --write

``python tests/support/estimate_digest.py`` replays the demo, prints the digest and whether it
matches the stored one. The digest is of one build: numba compiles for the host CPU and the system's
``libm``, so another machine may differ in the last bit (the stored samples say by how much).
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
#: Fields whose last value is stored beside the digest, to tell round-off from a real change.
SAMPLED = ("moisture_out", "moisture_out_std", "moisture_in", "moisture_in_std",
           "T_dryer_out_model", "T_cyclone_out_model")


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


def samples(messages: list[tuple[int, dict[str, Any]]]) -> dict[str, Any]:
    """The count of estimates and the last one's main fields, in full precision."""
    last = messages[-1][1] if messages else {}
    return {"estimates": len(messages), **{k: last.get(k) for k in SAMPLED}}


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

    return store_or_compare(digest(messages), samples(messages), STORED, args.write)


if __name__ == "__main__":
    sys.exit(main())
