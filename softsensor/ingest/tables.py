"""Reading and writing tables (CSV, Parquet) for historians, LIMS and spreadsheets.

CSV cells are read as text, so :mod:`softsensor.ingest.historian_export` decides what is a number, a
bad-quality string or a time (pandas would silently turn a column with one ``Bad`` into text
and guess date formats). Parquet keeps its typed columns. Every problem is one
:class:`~softsensor.errors.IngestError` line naming the file.

What is read is bounded before it is read, so that no export can take the machine's memory:
a CSV is first streamed in 1 MiB blocks to count its lines and measure the longest (a 50 MB
file of one line is refused after reading 64 kiB of it into memory at most), a Parquet file's
footer gives its rows, columns and uncompressed size (a 170 kB file can hold 3 million rows).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import pandas as pd

from softsensor.errors import IngestError, require_packages
from softsensor.ingest.cells import delimiter_hint

CSV_SUFFIXES: tuple[str, ...] = (".csv", ".txt", ".tsv")
#: Most rows read from a table unless the caller allows more (a map's ``source.max_rows``).
MAX_ROWS = 1_000_000
#: Longest line of a CSV [bytes]: a wide export of 500 tags is about 10 kB a line.
MAX_LINE_BYTES = 65_536
#: Most columns of a Parquet file, and its largest uncompressed size [bytes].
MAX_COLUMNS = 10_000
MAX_PARQUET_BYTES = 512 * 1024 * 1024
_BLOCK = 1 << 20
PARQUET_SUFFIXES: tuple[str, ...] = (".parquet", ".pq")


def table_kind(path: Path) -> str:
    """``"csv"`` or ``"parquet"`` from the file name; IngestError for anything else."""
    suffix = path.suffix.lower()
    if suffix in CSV_SUFFIXES:
        return "csv"
    if suffix in PARQUET_SUFFIXES:
        require_packages(f"{path}: Parquet", "pyarrow")
        return "parquet"
    raise IngestError(f"{path}: unknown table format {suffix or '(no suffix)'!r} "
                      f"(expected {', '.join(CSV_SUFFIXES + PARQUET_SUFFIXES)})")


def _csv_bounds(p: Path, max_rows: int, skip_rows: int) -> None:
    """Refuse a CSV with a line longer than :data:`MAX_LINE_BYTES` or more than ``max_rows``
    data rows, streaming it (memory: one block)."""
    lines, longest, current = 0, 0, 0
    with p.open("rb") as f:
        while block := f.read(_BLOCK):
            start = 0
            while (nl := block.find(b"\n", start)) >= 0:
                longest = max(longest, current + nl - start)
                current, start, lines = 0, nl + 1, lines + 1
            current += len(block) - start
            longest = max(longest, current)
            if longest > MAX_LINE_BYTES:
                raise IngestError(f"{p}: line {lines + 1} is longer than {MAX_LINE_BYTES} bytes "
                                  "(not a historian export, or the wrong delimiter?)")
            if lines - 1 - skip_rows > max_rows:
                raise IngestError(f"{p}: more than {max_rows} rows (split the export, or raise "
                                  "source.max_rows)")


def _parquet_bounds(p: Path, max_rows: int) -> None:
    """Refuse a Parquet file whose footer promises more than the bounds, before reading it."""
    import pyarrow.parquet as pq

    meta = pq.read_metadata(p)
    size = sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))
    if meta.num_rows > max_rows:
        raise IngestError(f"{p}: {meta.num_rows} rows, more than {max_rows} (split the export, "
                          "or raise source.max_rows)")
    if meta.num_columns > MAX_COLUMNS or size > MAX_PARQUET_BYTES:
        raise IngestError(f"{p}: {meta.num_columns} columns, {size / 2**20:.0f} MiB "
                          f"uncompressed: more than the {MAX_COLUMNS} columns and "
                          f"{MAX_PARQUET_BYTES // 2**20} MiB read at once")


def read_table(path: str | Path, *, delimiter: str = ",", skip_rows: int = 0,
               max_rows: int = MAX_ROWS, table: str = "source") -> pd.DataFrame:
    """A CSV (cells as text) or Parquet file as a DataFrame with a 0-based row index, its
    first ``skip_rows`` rows under the header left out (a units row), at most ``max_rows``
    rows (more: IngestError before the data is read). ``table``: the map's table of these
    settings, named in the hint for a wrong delimiter."""
    p = Path(path)
    kind = table_kind(p)
    if not p.is_file():
        raise IngestError(f"{p}: no such file")
    try:
        if kind == "csv":
            _csv_bounds(p, max_rows, skip_rows)
            frame = pd.read_csv(p, sep=delimiter, dtype=str, keep_default_na=False,
                                skipinitialspace=True, encoding="utf-8-sig",
                                skiprows=range(1, 1 + skip_rows), nrows=max_rows + 1)
        else:
            _parquet_bounds(p, max_rows)
            frame = pd.read_parquet(p).iloc[skip_rows:]
    except (ValueError, OSError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        hint = ""
        if kind == "csv" and isinstance(exc, pd.errors.ParserError):
            with contextlib.suppress(OSError, UnicodeDecodeError):
                with p.open(encoding="utf-8-sig") as f:
                    hint = delimiter_hint([f.readline().rstrip("\r\n")], table)
        raise IngestError(f"{p}: cannot read as {kind}: {first}{hint}") from exc
    if len(frame) > max_rows:  # the file grew since it was measured
        raise IngestError(f"{p}: more than {max_rows} rows")
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame.reset_index(drop=True)


def write_table(frame: pd.DataFrame, path: str | Path) -> Path:
    """Write ``frame`` as CSV or Parquet (by suffix), without its index."""
    p = Path(path)
    kind = table_kind(p)
    try:
        if kind == "csv":
            frame.to_csv(p, index=False)
        else:
            frame.to_parquet(p, index=False)
    except OSError as exc:
        raise IngestError(f"{p}: cannot write: {exc.strerror or exc}") from exc
    return p
