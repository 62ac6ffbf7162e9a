"""The calibration report page read back as a person reads it: the verdict, its errors, and
each section's tables as rows keyed by their header (``tests/calibration/
test_structure_search.py`` compares them with PARAMS.toml)."""

from __future__ import annotations

import html
import re
from dataclasses import dataclass, field
from html.parser import HTMLParser
from pathlib import Path

#: The verdict's errors: "dryer outlet A -> B °C, cyclone outlet C -> D °C, outlet moisture
#: E -> F % points".
ERRORS = re.compile(r"dryer outlet ([\d.]+) -> ([\d.]+) °C, cyclone outlet ([\d.]+) -> "
                    r"([\d.]+) °C, outlet moisture ([\d.]+) -> ([\d.]+) % points")


@dataclass
class Page:
    verdict: str
    #: the verdict's six figures: dryer, cyclone, moisture, each current then deployed
    headline_errors: list[str]
    #: each section's tables (heading -> tables -> rows keyed by the header)
    tables: dict[str, list[list[dict[str, str]]]] = field(default_factory=dict)
    text: str = ""


class _Reader(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.heading = ""
        self.tables: dict[str, list[list[list[str]]]] = {}
        self._cell: list[str] | None = None
        self._row: list[str] | None = None
        self._in_h2 = False

    def handle_starttag(self, tag: str, attrs) -> None:
        if tag == "h2":
            self._in_h2, self.heading = True, ""
        elif tag == "table":
            self.tables.setdefault(self.heading, []).append([])
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "h2":
            self._in_h2 = False
        elif tag in ("td", "th") and self._cell is not None and self._row is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.tables[self.heading][-1].append(self._row)
            self._row = None

    def handle_data(self, data: str) -> None:
        if self._in_h2:
            self.heading += data
        if self._cell is not None:
            self._cell.append(data)


def read_page(path: Path) -> Page:
    """The page at ``path`` (module docstring)."""
    text = path.read_text()
    verdict = html.unescape(re.search(r'<p class="verdict">(.*?)</p>', text, re.S).group(1))
    m = ERRORS.search(verdict)
    reader = _Reader()
    reader.feed(text)
    tables = {h: [[dict(zip(t[0], row, strict=True)) for row in t[1:]] for t in ts]
              for h, ts in reader.tables.items()}
    return Page(verdict, list(m.groups()) if m else [], tables,
                html.unescape(re.sub(r"<[^>]+>", " ", text)))


__all__ = ["Page", "read_page"]
