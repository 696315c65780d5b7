"""Result rows of ``render`` (:mod:`jobapi.rows`) and what a scored image's row takes from
the render that made it.

A render measures one thing: its own cost. Its row is ``render_seconds``: the wall time of
its passes less Dr.Jit's kernel compilation (no Mitsuba import, scene load, material
resolution or output writing), as the render kind measures it
(:func:`evaluators.render.kind.render_passes`) and records it in the job's manifest. For
renders made before it was recorded, the job's wall time stands in. Timings stay out of the
artifacts (same spec, same bytes), so they come from the job's record.

A glint material (``{"glint": {...}}``) adds its evaluator (``config.method``), the
example's side (``config.example``) and its memory, ``bytes_per_material``
(:func:`evaluators.render.sources.glint.layer_bytes`: the tiny example's NDF maps and lobes
from its ``generate.glint`` job's ``stats.json``, the Yan et al. export's lobes, or the
smooth GGX's two roughnesses; a clearcoat's are added), so a glint ladder charts error
against memory as well as time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jobapi.rows import ResultRow, RowSource, base_row, number


def material_source(material: Any) -> str | None:
    """The kind of a render's ``material`` param: ``"model"`` (a trained network, with or
    without the fabric it encodes), ``"fabric"``, ``"mitsuba"``, ``"merl"``, ...; the
    ``model`` key wins, so a network and the Monte Carlo fabric it stands for differ."""
    if not isinstance(material, Mapping) or not material:
        return None
    if "model" in material:
        return "model"
    return str(next(iter(material)))


def _glint_layer(
    src: RowSource,
    spec: Mapping[str, Any],
    method: str,
    texels: float,
    oversample: int,
    yan_rate: int = 1,
) -> tuple[float | None, int | None]:
    """Bytes and example side of one glint layer (``None`` where its data job is unknown)."""
    from evaluators.render.sources.glint import layer_bytes

    data = spec.get("data")
    stats = None
    made_by = src.source(data) if isinstance(data, str) else None
    if made_by is not None:
        stats = made_by.read("stats.json")
    stats = stats if isinstance(stats, Mapping) else {}
    size = number((stats.get("example") or {}).get("size"))
    tiny = number((stats.get("bytes") or {}).get("total"))
    nbytes = layer_bytes(
        method, tiny_bytes=tiny, texels_per_uv=texels, oversample=oversample, yan_rate=yan_rate
    )
    return nbytes, int(size) if size is not None else None


def glint_facts(src: RowSource, glint: Mapping[str, Any]) -> dict[str, Any]:
    """``bytes_per_material`` and config entries (``method``, ``example``; ``lookup`` and
    ``sampling`` where not the defaults) of a render's
    ``{"glint": glint}`` material (defaults as :class:`~evaluators.render.sources.glint.
    GlintSpec`'s: tiny_example, 256 texels per uv, oversample 2, yan_rate 1)."""
    method = str(glint.get("method") or "tiny_example")
    texels = number(glint.get("texels_per_uv"))
    texels = 256.0 if texels is None else texels
    over = number(glint.get("oversample"))
    over_i = 2 if over is None else int(over)
    rate = number(glint.get("yan_rate"))
    rate_i = 1 if rate is None else int(rate)
    nbytes, size = _glint_layer(src, glint, method, texels, over_i, rate_i)
    config: dict[str, Any] = {"method": method, "example": size, "texels_per_uv": texels}
    # The lookup rule and the sampler, only where they differ from the defaults (so that
    # the rows of older renders keep their config).
    for key, default in (("lookup", "flat"), ("sampling", "ggx_mix")):
        value = glint.get(key)
        if value is not None and value != default:
            config[key] = str(value)
    coat = glint.get("clearcoat")
    if isinstance(coat, Mapping):
        coat_method = str(coat.get("method") or method)
        coat_bytes, _ = _glint_layer(src, coat, coat_method, texels, over_i, rate_i)
        nbytes = None if nbytes is None or coat_bytes is None else nbytes + coat_bytes
        config["clearcoat"] = coat_method
    return {"bytes_per_material": nbytes, "config": config}


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
    if isinstance(material, Mapping) and isinstance(material.get("glint"), Mapping):
        glint = glint_facts(src, material["glint"])
        config.update(glint["config"])
        facts["bytes_per_material"] = glint["bytes_per_material"]
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
