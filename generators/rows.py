"""Result rows of the dataset kinds (:mod:`jobapi.rows`): what a generator measures about
its own output, taken from its summary table (one row per table row and measured column).

- ``generate.merl``: per material, the tabulation's figures (``tabulation.*``) and the
  missing bins of a measurement;
- ``generate.fabric``: the Monte Carlo throughput of ``stats.json`` (samples per second);
- ``generate.glint``: the tiny example's bytes, the reference's, their ratio, the
  precompute seconds, each row costed with the example's own bytes (``bytes_per_material``:
  its NDF maps and lobes) and its size and NDF resolution in ``config``;
- ``generate.btf``: the Monte Carlo standard error of the slices (mean, relative), at the
  job's spp.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
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


def fabric_stats_rows(src: RowSource) -> list[ResultRow]:
    """``generate.fabric``: ``samples_per_second`` and ``seconds`` of ``stats.json``."""
    doc = src.read("stats.json")
    if not isinstance(doc, Mapping):
        return []
    return [
        base_row(
            src,
            k,
            v,
            candidate=str(doc.get("backend") or "monte carlo"),
            lower_is_better=k == "seconds",
        )
        for k in ("samples_per_second", "seconds")
        if (v := number(doc.get(k))) is not None
    ]


def glint_rows(summary: Summary) -> RowsHook:
    """``generate.glint``: the summary's ``bytes``, ``reference_bytes``, ``memory_ratio`` and
    ``precompute_seconds``, each with ``bytes_per_material`` (the example's ``bytes``) and
    ``config`` (``size``, ``ndf_resolution``, ``levels``, ``lobes``)."""
    measured = ("bytes", "reference_bytes", "memory_ratio", "precompute_seconds")
    described = ("size", "ndf_resolution", "levels", "lobes")

    def rows(src: RowSource) -> list[ResultRow]:
        table = summary(src.read)
        if table is None:
            return []
        out: list[ResultRow] = []
        for label, row in table.rows.items():
            config = {k: row[k] for k in described if number(row.get(k)) is not None}
            nbytes = number(row.get("bytes"))
            out += [
                base_row(src, col, v, candidate=label, config=config, bytes_per_material=nbytes)
                for col in measured
                if (v := number(row.get(col))) is not None
            ]
        return out

    return rows
