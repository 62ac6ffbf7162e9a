"""Reading and writing tables (CSV, Parquet) for historians, LIMS and spreadsheets.

CSV cells are read as text, so :mod:`softsensor.ingest.historian` decides what is a number, a
bad-quality string or a time (pandas would silently turn a column with one ``Bad`` into text
and guess date formats). Parquet keeps its typed columns. Every problem is one
:class:`~softsensor.errors.IngestError` line naming the file.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from softsensor.errors import IngestError, require_packages

CSV_SUFFIXES: tuple[str, ...] = (".csv", ".txt", ".tsv")
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


def read_table(path: str | Path, *, delimiter: str = ",") -> pd.DataFrame:
    """A CSV (cells as text) or Parquet file as a DataFrame with a 0-based row index."""
    p = Path(path)
    kind = table_kind(p)
    if not p.is_file():
        raise IngestError(f"{p}: no such file")
    try:
        if kind == "csv":
            frame = pd.read_csv(p, sep=delimiter, dtype=str, keep_default_na=False,
                                skipinitialspace=True, encoding="utf-8-sig")
        else:
            frame = pd.read_parquet(p)
    except (ValueError, OSError, UnicodeDecodeError, pd.errors.ParserError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise IngestError(f"{p}: cannot read as {kind}: {first}") from exc
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
