"""``generate.btf``: BTF slices path-traced with Mitsuba 3 (Xu et al., Sec. 3.1).

The runner builds the surface (a flat plane of any Mitsuba BSDF, or a seeded procedural
patch as a displaced mesh), splits the light x view pairs into shards, renders each shard's
slices with :class:`~evaluators.render.btf.slices.SliceRenderer` through the job's executor
(resumable: finished shards are kept), and writes:

====================  =======================================================================
artifact              content
====================  =======================================================================
``slices-XXXX.npz``   ``wi`` ``(N, 3)``, ``wo`` ``(N, 3)``, ``rgb`` ``(N, H, W, 3)`` float32
                      (or float16), ``stderr`` ``(N,)`` (:mod:`storage.formats.btf`)
``btf.json``          resolution, count, shards, convention, units, the directions (angles),
                      surface, spp, max_depth, Monte Carlo error summary, Mitsuba variant
``height.exr``        the height field (patch units, same value in R, G, B; zeros for a flat
                      plane)
``albedo.exr``        procedural surfaces: linear RGB albedo (principled ``base_color``)
``roughness.exr``     procedural surfaces: principled ``roughness`` (in R, G, B)
``preview.png``       a grid of slices and the centre texel's apparent BRDF (Fig. 9)
====================  =======================================================================

Each slice is seeded by its index alone, so the same spec gives the same bytes whatever the
sharding or the executor.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.render.btf.patch import flat_shape, procedural_mesh
from evaluators.render.btf.slices import SliceRenderer
from evaluators.render.sources.common import load_bsdf
from generators.btf.params import BtfGenParams, FlatSurface
from generators.btf.preview import PreviewCollector
from generators.rows import summary_rows
from jobapi.kinds import Figure, Kind, register
from jobapi.results import ArtifactReader, ResultTable
from materials.backend import active_variant, load_mitsuba
from materials.btf.directions import pair_count_label, to_angles
from materials.btf.surfaces import SurfaceMaps, procedural_surface
from storage.formats.btf import BtfIndexDocument, index_document, shard_bytes, shard_name
from storage.formats.exr import exr_bytes

if TYPE_CHECKING:
    from jobapi.context import JobContext

LAYOUT = """
- `slices-XXXX.npz` (from `0000`): `wi` `(N, 3)` light and `wo` `(N, 3)` view directions
  (float32 unit vectors, z up, away from the surface), `rgb` `(N, H, W, 3)` float32 (or
  float16 with `"dtype": "float16"`), `[row = y, column = x]`, in UBO2014's convention
  `BTF = L_o / E_perp` (1/sr, foreshortening included: a flat Lambertian plane gives
  `albedo / pi * cos(theta_i)`), and `stderr` `(N,)`: each slice's Monte Carlo standard
  error (RMS over texels and channels; an upper bound with the default stratified jitter).
- `btf.json`: `resolution` `[H, W]`, `count`, `shards` (`name`, `count`, in slice order),
  `convention`, `units`, `directions` (`[theta_i, phi_i, theta_o, phi_o]` degrees per slice),
  `surface`, `spp`, `max_depth`, `stderr` (mean, max), `mitsuba_variant`.
- `height.exr` (patch units; the patch's side is 1), `albedo.exr`, `roughness.exr`: the
  procedural surface's maps, `[row = y, column = x]`, texel centres at `(i + 0.5) / n`.
- `preview.png`: a grid of slices and the centre texel's apparent BRDF (lights down, views
  across), as in Xu et al.'s Fig. 9.
"""


@dataclass(frozen=True)
class ShardTask:
    """One shard's work: picklable, rendered in a worker process."""

    surface: dict[str, Any]
    maps: SurfaceMaps | None
    wi: np.ndarray
    wo: np.ndarray
    seeds: tuple[int, ...]
    resolution: int
    spp: int
    max_depth: int
    dtype: str
    stratified: bool = True


_RENDERERS: dict[str, SliceRenderer] = {}


def _renderer(task: ShardTask) -> SliceRenderer:
    # One scene per worker process and surface (the mesh build is the slow part at 400^2).
    import hashlib
    import pickle

    key = hashlib.sha256(pickle.dumps((task.surface, task.maps, task.max_depth))).hexdigest()
    if key not in _RENDERERS:
        _RENDERERS.clear()
        mi = load_mitsuba()
        if task.maps is not None:
            shape = procedural_mesh(mi, task.maps)
        else:
            shape = flat_shape(mi, load_bsdf(task.surface["bsdf"], mi, "surface.bsdf"))
        _RENDERERS[key] = SliceRenderer(mi, shape, max_depth=task.max_depth)
    return _RENDERERS[key]


def render_shard(task: ShardTask) -> bytes:
    """The shard's ``.npz`` bytes: every slice of ``task``."""
    renderer = _renderer(task)
    res = task.resolution
    rgb = np.empty((len(task.seeds), res, res, 3), dtype=task.dtype)
    stderr = np.empty(len(task.seeds), np.float32)
    for k, seed in enumerate(task.seeds):
        s = renderer.render(task.wi[k], task.wo[k], res, task.spp, seed, stratified=task.stratified)
        rgb[k] = s.rgb
        stderr[k] = s.stderr
    return shard_bytes(task.wi, task.wo, rgb, stderr, task.dtype)


def surface_maps(params: BtfGenParams, ctx: JobContext) -> SurfaceMaps | None:
    """The procedural surface's maps (seeded from the job), or ``None`` for a flat BSDF."""
    s = params.surface
    if isinstance(s, FlatSurface):
        return None
    size = s.size or params.effective().resolution
    return procedural_surface(s.procedural, size, ctx.rng("generate.btf/surface"), relief=s.relief)


def stderr_summary(stderr: np.ndarray, values: np.ndarray) -> dict[str, float]:
    """``btf.json``'s ``stderr``: mean and max of the slices' errors, and the mean relative
    to the mean BTF value (of the centre texels)."""
    scale = max(float(np.mean(values)), 1e-12)
    return {
        "mean": float(np.mean(stderr)),
        "max": float(np.max(stderr)),
        "relative": float(np.mean(stderr)) / scale,
    }


def _gray(x: np.ndarray) -> np.ndarray:
    return np.repeat(np.asarray(x, np.float32)[..., None], 3, axis=2)


def run_generate_btf(params: BtfGenParams, ctx: JobContext) -> None:
    """Render every slice into shards, then the index, the maps and the preview."""
    eff = params.effective()
    res, spp, max_depth, per_shard = eff.resolution, eff.spp, eff.max_depth, eff.shard_slices
    wi, wo = params.pairs()
    n = len(wi)
    surface = params.surface.model_dump(mode="json")
    maps = surface_maps(params, ctx)
    if isinstance(params.surface, FlatSurface):
        # Fail before queueing hours of work if Mitsuba cannot build the BSDF.
        load_bsdf(params.surface.bsdf, load_mitsuba(), "surface.bsdf")
    seeds = [ctx.sub_seed(f"generate.btf/slice/{i}") for i in range(n)]
    tasks, names = [], []
    for k, lo in enumerate(range(0, n, per_shard)):
        hi = min(n, lo + per_shard)
        tasks.append(
            ShardTask(
                surface=surface, maps=maps, wi=wi[lo:hi], wo=wo[lo:hi],
                seeds=tuple(seeds[lo:hi]), resolution=res, spp=spp,
                max_depth=max_depth, dtype=params.dtype,
                stratified=params.jitter == "stratified",
            )
        )  # fmt: skip
        names.append(shard_name(k))

    preview = PreviewCollector([len(t.seeds) for t in tasks], names, (res, res))
    ctx.progress(0.0, f"{pair_count_label(n)} of {res}x{res} texels at {spp} spp")
    ctx.map_artifact_shards(
        render_shard, tasks, names, media_type="application/x-npz",
        on_result=preview, label="shard", progress_range=(0.0, 0.95),
    )  # fmt: skip

    ti, pi_ = to_angles(wi)
    to, po = to_angles(wo)
    angles = np.round(np.stack([ti, pi_, to, po], axis=1), 6).tolist()
    doc = index_document(
        (res, res),
        [(names[k], len(t.seeds)) for k, t in enumerate(tasks)],
        source="generate.btf",
        surface=surface,
        directions=angles,
        spp=spp,
        max_depth=max_depth,
        jitter=params.jitter,
        dtype=params.dtype,
        patch={"side": 1.0, "tiles": 3 if maps is not None else None,
               "maps_size": None if maps is None else maps.size},
        stderr=stderr_summary(preview.stderr, preview.texel_values),
        mitsuba_variant=active_variant(),
    )  # fmt: skip
    ctx.put_json("btf.json", doc)
    if maps is None:
        ctx.put_bytes("height.exr", exr_bytes(np.zeros((res, res, 3), np.float32)), "image/x-exr")
    else:
        ctx.put_bytes("height.exr", exr_bytes(_gray(maps.height)), "image/x-exr")
        ctx.put_bytes("albedo.exr", exr_bytes(maps.albedo), "image/x-exr")
        ctx.put_bytes("roughness.exr", exr_bytes(_gray(maps.roughness)), "image/x-exr")
    label = surface.get("procedural") or surface["bsdf"].get("type", "bsdf")
    title = f"generate.btf: {label}, {pair_count_label(n)}, {res}x{res}, {spp} spp"
    ctx.put_bytes("preview.png", preview.png(wi, wo, title), "image/png")
    rel = doc["stderr"]["relative"]
    ctx.progress(1.0, f"{n} slices; Monte Carlo error {100 * rel:.2f} % of the mean (RMS)")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row: slices, resolution, spp and the Monte Carlo error."""
    doc = read("btf.json")
    if not isinstance(doc, dict):
        return None
    err = doc.get("stderr") or {}
    row = {
        "slices": doc.get("count"),
        "resolution": (doc.get("resolution") or [None])[0],
        "spp": doc.get("spp"),
        "max_depth": doc.get("max_depth"),
        "stderr_mean": err.get("mean"),
        "stderr_relative": err.get("relative"),
    }
    surface = doc.get("surface") or {}
    name = surface.get("procedural") or (surface.get("bsdf") or {}).get("type", "surface")
    return ResultTable(
        title="BTF slices",
        label_header="Surface",
        columns=list(row),
        rows={str(name): row},
        ranked=False,
    )


register(
    Kind(
        name="generate.btf",
        variant_bytes=True,
        params=BtfGenParams,
        runner=run_generate_btf,
        description="BTF slices (Xu et al. 2025, Sec. 3.1) path-traced with Mitsuba 3 in "
        "UBO2014's convention: a flat plane of any Mitsuba BSDF or a procedural displaced "
        "surface (leather, fabric, wood, stone), one slice per light x view pair.",
        artifacts=("slices-0000.npz", "btf.json", "height.exr", "preview.png"),
        documents={"btf.json": BtfIndexDocument},
        figures=(
            Figure(
                "preview.png",
                caption="A grid of slices and the centre texel's apparent BRDF (as Fig. 9 of "
                "Xu et al.).",
                lead=True,
            ),
        ),
        smoke={
            "surface": {"procedural": "stone", "size": 8},
            "directions": [[0, 0, 0, 0], [45, 0, 30, 180]],
            "resolution": 8,
            "spp": 2,
        },
        summary=summarize,
        rows=summary_rows(summarize, ("stderr_mean", "stderr_relative")),
        metrics=("stderr_mean", "stderr_relative"),
        layout=LAYOUT,
    )
)
