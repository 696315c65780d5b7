"""Result rows of ``generate.fabric`` (:mod:`jobapi.rows`): the Monte Carlo throughput
(samples per second, and the seconds it took) of the job's manifest,
``timings.measured.throughput``, or of ``stats.json`` for a job made before timings moved
to the manifest."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.documents import read_typed
from jobapi.rows import ResultRow, RowSource, base_row, number
from storage.formats.fabric_documents import FabricStats


def fabric_stats_rows(src: RowSource) -> list[ResultRow]:
    """``generate.fabric``: ``samples_per_second`` and ``seconds`` of the manifest's
    ``timings.measured.throughput`` (older jobs: of ``stats.json``), its ``backend`` from
    ``stats.json``."""
    doc = read_typed(src.read("stats.json"), FabricStats)
    if doc is None:
        return []
    timed = src.job.measured.get("throughput")
    times: Mapping[str, Any] = timed if isinstance(timed, Mapping) else doc
    return [
        base_row(
            src,
            k,
            v,
            candidate=doc["backend"],
            lower_is_better=k == "seconds",
        )
        for k in ("samples_per_second", "seconds")
        if (v := number(times.get(k))) is not None
    ]
