"""Result rows of the dataset kinds (:mod:`jobapi.rows`) taken from their summary tables:
one row per table row and measured column. Shared by the generator families and knowing none
of them: ``generate.merl`` and ``generate.btf`` row their summaries' columns through
:func:`summary_rows`; ``generate.fabric`` (:mod:`generators.fabric.rows`) and
``generate.glint`` (:mod:`generators.glint.rows`) keep their own hooks with their kinds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from jobapi.results import ArtifactReader, ResultTable
from jobapi.rows import ResultRow, RowsHook, RowSource, base_row, number

Summary = Callable[[ArtifactReader], ResultTable | None]


def table_rows(
    src: RowSource, table: ResultTable | None, keep: Callable[[str], bool], **fields: Any
) -> list[ResultRow]:
    """A row per numeric cell of ``table`` whose column ``keep`` accepts (the table row's
    label as the candidate)."""
    if table is None:
        return []
    return [
        base_row(src, col, v, candidate=label, **fields)
        for label, row in table.rows.items()
        for col in table.columns
        if keep(col) and (v := number(row.get(col))) is not None
    ]


def summary_rows(summary: Summary, columns: Iterable[str] = (), prefix: str = "") -> RowsHook:
    """A rows hook over a kind's summary hook: the ``columns`` named, or those starting with
    ``prefix``."""
    named = frozenset(columns)

    def rows(src: RowSource) -> list[ResultRow]:
        spp = number(src.job.params.get("spp"))
        fields: dict[str, Any] = {"spp": int(spp)} if spp is not None else {}
        return table_rows(
            src,
            summary(src.read),
            lambda c: c in named or bool(prefix and c.startswith(prefix)),
            **fields,
        )

    return rows
