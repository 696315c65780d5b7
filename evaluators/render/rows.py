"""Result rows of ``render`` (:mod:`jobapi.rows`) and what a scored image's row takes from
the render that made it.

A render measures one thing: its own cost. Its row is ``render_seconds`` (the job's wall
time: scene load, JIT compile, every pass), with the scene, the spp and the material's
source (``config``). Timings stay out of the artifacts (same spec, same bytes), so they
come from the job's record.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.rows import ResultRow, RowSource, base_row


def material_source(material: Any) -> str | None:
    """The kind of a render's ``material`` param: ``"model"`` (a trained network, with or
    without the fabric it encodes), ``"fabric"``, ``"mitsuba"``, ``"merl"``, ...; the
    ``model`` key wins, so a network and the Monte Carlo fabric it stands for differ."""
    if not isinstance(material, Mapping) or not material:
        return None
    if "model" in material:
        return "model"
    return str(next(iter(material)))


def render_facts(src: RowSource) -> dict[str, Any]:
    """The row fields a render contributes to a row about its image: ``scene``, ``spp``,
    ``render_seconds``, ``seed`` and ``config`` (source, resolution, max_depth, spp);
    ``{}`` when ``src`` is not a render."""
    if src.job.kind != "render":
        return {}
    p = src.job.params
    spp = p.get("spp")
    config = {
        "source": material_source(p.get("material")),
        "resolution": p.get("resolution"),
        "max_depth": p.get("max_depth"),
        "spp": spp,
    }
    material = p.get("material")
    if isinstance(material, Mapping) and isinstance(material.get("material"), str):
        config["material"] = material["material"]
    return {
        "scene": p.get("scene"),
        "spp": spp if isinstance(spp, int) else None,
        "render_seconds": src.job.run_seconds,
        "seed": src.job.seed,
        "config": config,
    }


def render_rows(src: RowSource) -> list[ResultRow]:
    """One row: ``render_seconds`` of this render (none while the time is unknown)."""
    seconds = src.job.run_seconds
    if seconds is None:
        return []
    facts = render_facts(src)
    return [base_row(src, "render_seconds", float(seconds), **facts)]
