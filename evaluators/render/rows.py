"""Result rows of ``render`` (:mod:`jobapi.rows`) and what a scored image's row takes from
the render that made it.

A render measures one thing: its own cost. Its row is ``render_seconds``: the wall time of
its passes less Dr.Jit's kernel compilation (no Mitsuba import, scene load, material
resolution or output writing), as the render kind measures it
(:func:`evaluators.render.kind.render_passes`) and records it in the job's manifest. For
renders made before it was recorded, the job's wall time stands in. Timings stay out of the
artifacts (same spec, same bytes), so they come from the job's record.

A material source may add facts of its own (``config`` entries and ``bytes_per_material``):
its ``row_facts`` hook, registered with the source next to its resolver
(:mod:`evaluators.render.sources.common`; e.g. a glint material's evaluator, example side
and memory, :func:`evaluators.render.sources.glint.glint_row_facts`). This module names no
source.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from evaluators.render.sources import material_sources  # the built-ins, registered
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
    facts: dict[str, Any] = {}
    source = material_sources().get(str(config["source"]))
    if source is not None and source.row_facts is not None and isinstance(material, Mapping):
        own = source.row_facts(src, material)
        config.update(own.config)
        facts["bytes_per_material"] = own.bytes_per_material
    return {
        "scene": p.get("scene"),
        "spp": spp if isinstance(spp, int) else None,
        "render_seconds": render_seconds(src),
        "seed": src.job.seed,
        "config": config,
        **facts,
    }


def render_seconds(src: RowSource) -> float | None:
    """The render's own time (``measured["render_seconds"]``), else the job's wall time."""
    own = src.job.measured.get("render_seconds")
    return float(own) if isinstance(own, (int, float)) else src.job.run_seconds


def render_rows(src: RowSource) -> list[ResultRow]:
    """One row: ``render_seconds`` of this render (none while the time is unknown)."""
    seconds = render_seconds(src)
    if seconds is None:
        return []
    facts = render_facts(src)
    return [base_row(src, "render_seconds", float(seconds), **facts)]
