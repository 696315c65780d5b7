"""Tables that fit the terminal: a table of many value columns is split into several
tables of the columns that fit side by side, each repeating the label column, instead of
being squeezed until its headers and numbers wrap letter by letter."""

from __future__ import annotations

from collections.abc import Sequence

from rich.table import Table
from rich.text import Text

#: Characters a column takes beyond its content: one space of padding each side and a
#: border.
COLUMN_OVERHEAD = 3


def _natural(header: str, cells: Sequence[str]) -> int:
    return max([len(header), *(len(c) for c in cells)]) + COLUMN_OVERHEAD


def column_chunks(widths: Sequence[int], first: int, total: int) -> list[list[int]]:
    """Indices of value columns, grouped so that ``first`` (the label column) plus each
    group's ``widths`` fit in ``total`` characters (a column wider than that gets a group
    of its own)."""
    chunks: list[list[int]] = []
    used = total + 1  # forces a new chunk for the first column
    for i, w in enumerate(widths):
        if used + w > total:
            chunks.append([])
            used = first + 1
        chunks[-1].append(i)
        used += w
    return chunks


def fitted_tables(
    title: str,
    label_header: str,
    headers: Sequence[str],
    rows: Sequence[tuple[str, Sequence[str]]],
    width: int,
) -> list[Table]:
    """One table, or several when the columns do not fit in ``width`` characters; each
    has the label column first. Value cells are right-aligned text."""
    labels = [label for label, _ in rows]
    first = _natural(label_header, labels)
    widths = [_natural(h, [cells[i] for _, cells in rows]) for i, h in enumerate(headers)]
    chunks = column_chunks(widths, first, width) if headers else [[]]
    tables = []
    for n, chunk in enumerate(chunks, start=1):
        part = f" ({n}/{len(chunks)})" if len(chunks) > 1 else ""
        table = Table(title=f"{title}{part}")
        table.add_column(label_header, overflow="fold")
        for i in chunk:
            table.add_column(headers[i], justify="right", overflow="fold")
        for label, cells in rows:
            table.add_row(Text(label), *(Text(cells[i]) for i in chunk))
        tables.append(table)
    return tables
