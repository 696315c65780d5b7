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


Cell = str | Text


def _len(cell: Cell) -> int:
    return cell.cell_len if isinstance(cell, Text) else len(cell)


def _natural(header: str, cells: Sequence[Cell]) -> int:
    return max([len(header), *(_len(c) for c in cells)]) + COLUMN_OVERHEAD


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
    rows: Sequence[tuple[str, Sequence[Cell]]],
    width: int,
) -> list[Table]:
    """One table, or several when the columns do not fit in ``width`` characters; each
    has the label column first. Value cells are right-aligned text (a :class:`Text` keeps
    its style)."""
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
            table.add_row(Text(label), *(_text(cells[i]) for i in chunk))
        tables.append(table)
    return tables


def _text(cell: Cell) -> Text:
    return cell if isinstance(cell, Text) else Text(cell)


def chunk_count(headers: Sequence[str], rows: Sequence[tuple[str, Sequence[Cell]]],
                label_header: str, width: int) -> int:  # fmt: skip
    """How many tables :func:`fitted_tables` makes of these columns in ``width``."""
    first = _natural(label_header, [label for label, _ in rows])
    widths = [_natural(h, [cells[i] for _, cells in rows]) for i, h in enumerate(headers)]
    return len(column_chunks(widths, first, width)) if headers else 1


def blocks(have: Sequence[tuple[str, Sequence[str]]]) -> list[tuple[list[str], list[str]]]:
    """``(labels, columns)`` groups of a sparse table (``have``: each label and the
    columns it has a value in): labels that share a column are in one group, with every
    column any of them has, in order of first appearance. A table of unrelated results
    (a render's image statistics, a MERL collection's table quality, a model's scores)
    becomes one table each instead of one wide table of mostly empty cells."""
    group_of: dict[str, int] = {}
    parent: list[int] = []

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for n, (_, cols) in enumerate(have):
        parent.append(n)
        for col in cols:
            if col in group_of:
                a, b = find(group_of[col]), find(n)
                parent[max(a, b)] = min(a, b)
            else:
                group_of[col] = n
    out: dict[int, tuple[list[str], list[str]]] = {}
    for n, (label, cols) in enumerate(have):
        labels, columns = out.setdefault(find(n), ([], []))
        labels.append(label)
        columns.extend(c for c in cols if c not in columns)
    return list(out.values())
