"""docs/interface.md states the names softsensor/signals.py defines: the two must not drift.

The page is what a DCS engineer or a recorded day from another site relies on; the module is
what the code uses. Every signal (with its unit), topic, Zenoh key, health state and diagnosis
cause in one is in the other.
"""

from __future__ import annotations

import re

from paths import REPO

from softsensor import signals

DOC = (REPO / "docs" / "interface.md").read_text()


def _section(number: int) -> str:
    start = DOC.index(f"\n## {number}.")
    end = DOC.find("\n## ", start + 1)
    return DOC[start:end if end >= 0 else None]


def _table(text: str) -> dict[str, str]:
    """First two cells of each table row whose first cell is a `code` name."""
    rows = re.findall(r"^\| `([^`]+)` \| [^|]* \| ([^|]*) \|$", text, flags=re.M)
    return {name: unit.strip() for name, unit in rows}


def _unit(doc_unit: str) -> str:
    """The doc's readable unit as signals.py writes it."""
    if doc_unit.startswith("%"):
        return "%"
    return "kg/kg" if doc_unit.startswith("kg water") else doc_unit


def test_every_scan_signal_with_its_unit():
    table = _table(_section(1))
    documented = {n: _unit(u) for n, u in table.items() if n != signals.LAB_SIGNAL}
    assert documented == signals.SCAN_SIGNALS
    assert _unit(table[signals.LAB_SIGNAL]) == "kg/kg"


def test_topics_keys_states_and_causes():
    topics = set(re.findall(r"^\| `(/[^`]+)` \|", _section(2), flags=re.M))
    assert topics == {signals.TOPIC_SCAN, signals.TOPIC_LAB, signals.TOPIC_ESTIMATE,
                      signals.TOPIC_HEALTH}
    keys = set(re.findall(r"`([a-z]+/<unit>/[a-z]+)`", _section(3)))
    # the contract's four, and the project's own advice (issue 50, docs/interface.md)
    assert {signals.zenoh_key(k, "<unit>")
            for k in ("scan", "lab", "estimate", "health", "advice")} == keys
    states = re.search(r"`status` \(([^)]*)\)", _section(2)).group(1)
    assert tuple(re.findall(r"`([a-z]+)`", states)) == signals.HEALTH_STATES
    causes = tuple(re.findall(r"^\| `([a-z_]+)` \|", _section(5), flags=re.M))
    assert causes == signals.CAUSES
