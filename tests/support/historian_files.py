"""Historian maps made from the shipped example (``replay/historian-map.toml``) with one thing
wrong, for the tests of the import's checks and of what a replay says about the day."""

from __future__ import annotations

from pathlib import Path

from paths import REPLAY


def kg_per_h_map(tmp_path: Path, lab: str | None = None) -> Path:
    """The shipped example's map with the fibre flow (really t/h) declared kg/h."""
    text = (REPLAY / "historian-map.toml").read_text()
    head, sep, rest = text.partition("[signals.m_fiber]")
    rest = rest.replace('unit = "t/h"', 'unit = "kg/h"', 1)
    if lab is not None:
        rest = rest.split("[lab]")[0] + lab
    p = tmp_path / "map.toml"
    p.write_text(head + sep + rest)
    return p


__all__ = ["kg_per_h_map"]
