"""Result rows of ``generate.fabric`` (:mod:`jobapi.rows`): the Monte Carlo throughput of
``stats.json`` (samples per second, and the seconds it took)."""

from __future__ import annotations

from collections.abc import Mapping

from jobapi.rows import ResultRow, RowSource, base_row, number


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
