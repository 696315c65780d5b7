"""Result rows of ``generate.glint`` (:mod:`jobapi.rows`): the tiny example's bytes, the
reference's, their ratio and the precompute seconds (the manifest's
``timings.measured.precompute_seconds``, or ``stats.json``'s for a job made before timings
moved to the manifest), each row costed with the example's own
bytes (``bytes_per_material``: its NDF maps and lobes) and its size and NDF resolution in
``config``."""

from __future__ import annotations

from generators.rows import Summary
from jobapi.rows import ResultRow, RowsHook, RowSource, base_row, number


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
        timed = number(src.job.measured.get("precompute_seconds"))
        for label, row in table.rows.items():
            if timed is not None:
                row = {**row, "precompute_seconds": timed}
            config = {k: row[k] for k in described if number(row.get(k)) is not None}
            nbytes = number(row.get("bytes"))
            out += [
                base_row(src, col, v, candidate=label, config=config, bytes_per_material=nbytes)
                for col in measured
                if (v := number(row.get(col))) is not None
            ]
        return out

    return rows
