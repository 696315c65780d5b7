"""``generate.glint``: tiny-example multi-scale NDF maps (Xing et al. 2024, Sec. 5).

The runner makes (or reads) the tiny example, seeds its 4D Gaussian lobes
(:mod:`materials.glints.lobes`), precomputes the multi-scale NDF maps of Eq. 2
(:mod:`materials.glints.ndf_maps`), and writes:

==================  ==========================================================================
artifact            content
==================  ==========================================================================
``example.exr``     the example, ``(n, n, 3)`` float32 unit normals (row = y, texel centres at
                    i + 0.5, bilinear, tiled)
``ndf.npz``         ``level_<l>`` float32 ``(r, r, R, R)`` for l = 0 .. log2(n) - 1,
                    r = n / 2**(l+1), ``[ty, tx, iy, ix]``, each cell the mean P-NDF density
                    over its cell of s = (n_x, n_y) in ``[-e, e]^2`` (edges
                    ``linspace(-e, e, R + 1)``); scalars ``sigma_r``, ``extent``,
                    ``resolution``, ``lobe_rate``
``lobes.npz``       the lobes: ``u``, ``s``, ``jacobian``, ``weight``, ``sigma_h``,
                    ``sigma_r``, ``size``, ``rate``
``preview.png``     the example, the preview surface and one NDF image per level, labelled
``stats.json``      the example (size, type, the size it was cropped from); precompute
                    seconds; bytes of the NDF maps plus lobes; bytes the explicit
                    reference (Yan et al.) needs at ``reference_resolution`` and the same
                    lobe rate. Its timings vary between runs: the one non-deterministic
                    artifact.
==================  ==========================================================================
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from generators.glint.params import GlintGenParams, MapExample, ProceduralExample
from generators.glint.preview import preview_png
from generators.glint.rows import glint_rows
from jobapi.documents import read_typed
from jobapi.errors import FormatError, JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.results import ArtifactReader, ResultTable
from materials.glints.examples import procedural_example
from materials.glints.lobes import LOBE_BYTES, make_lobes
from materials.glints.ndf_maps import auto_extent, map_bytes, ndf_maps
from materials.glints.surface import Surface, export_normal_map
from storage.formats.exr import exr_bytes
from storage.formats.glint_stats import GlintStats
from storage.formats.normal_map import read_normal_map
from storage.formats.npz import npz_bytes

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Preview surface side, in examples.
PREVIEW_EXAMPLES = 4
#: The artifacts' layouts, for the README.
LAYOUT = """
- `example.exr`: `(n, n, 3)` float32 tangent-space unit normals, z up, `[row = y, column = x]`,
  texel centres at `i + 0.5`, bilinear between centres, tiled.
- `ndf.npz`: `level_<l>` float32 `(r, r, R, R)` for `l = 0 .. log2(n) - 1`,
  `r = n / 2**(l+1)`, indexed `[ty, tx, iy, ix]`; tile `(tx, ty)` covers texels
  `[tx n/r, (tx+1) n/r) x [ty n/r, (ty+1) n/r)`; each cell the mean P-NDF density over its
  cell of `s = (n_x, n_y)` in `[-e, e]^2` (edges `linspace(-e, e, R + 1)`); a level is the
  mean of its four children; scalars `sigma_r`, `extent` (e), `resolution`, `lobe_rate`.
- `lobes.npz`: the 4D Gaussians: `u` `(N, 2)` seed positions (texels), `s` `(N, 2)`
  projected normals, `jacobian` `(N, 2, 2)` (`ds_a / du_b`), scalars `weight` (h^2),
  `sigma_h`, `sigma_r`, `size`, `rate`.
- `stats.json`: `bytes` (NDF maps, lobes,
  total), `reference` (the explicit Yan et al. map at `reference_resolution`: lobes, bytes),
  `memory_ratio`. The precompute time is not an artifact (timings vary between runs): the
  job manifest's `timings.measured.precompute_seconds`.
"""


def load_example(example: ProceduralExample | MapExample, ctx: JobContext) -> np.ndarray:
    """The example's ``(n, n, 3)`` float32 normals: generated (seeded from the job's seed) or
    read and checked from the referenced normal map (``JobFailed`` naming it)."""
    if isinstance(example, ProceduralExample):
        rng = ctx.rng("generate.glint/example")
        return procedural_example(example.procedural, example.size, rng, slope=example.slope)
    path = ctx.resolve(example.normal_map)
    name = ctx.ref_record(example.normal_map).name
    try:
        return read_normal_map(path, name)
    except FormatError as exc:
        raise JobFailed(f"example.normal_map: {exc}") from None


def run_generate_glint(params: GlintGenParams, ctx: JobContext) -> None:
    """Make the example, its lobes and NDF maps, and store the artifacts."""
    ctx.progress(0.0, "example")
    normals = load_example(params.example, ctx)
    full = int(normals.shape[0])
    if params.crop is not None:
        if params.crop > full:
            raise JobFailed(f"crop: {params.crop} is larger than the example ({full}x{full})")
        normals = np.ascontiguousarray(normals[: params.crop, : params.crop])
    n = int(normals.shape[0])
    eff = params.effective()
    rate, res = eff.lobe_rate, eff.ndf_resolution
    started = time.perf_counter()
    lobes = make_lobes(normals, rate=rate, sigma_r=params.sigma_r)
    extent = params.extent or auto_extent(lobes)
    ctx.progress(0.1, f"NDF maps: {n}x{n} example, {len(lobes)} lobes, R = {res}")
    maps = ndf_maps(lobes, res, extent)
    seconds = time.perf_counter() - started
    ctx.check_cancelled()

    ctx.put_bytes("example.exr", exr_bytes(normals), "image/x-exr")
    arrays: dict[str, np.ndarray] = {f"level_{i}": m for i, m in enumerate(maps)}
    arrays.update(
        sigma_r=np.array(params.sigma_r, np.float32),
        extent=np.array(extent, np.float32),
        resolution=np.array(res, np.int32),
        lobe_rate=np.array(rate, np.int32),
    )
    ctx.put_bytes("ndf.npz", npz_bytes(arrays), "application/x-npz")
    ctx.put_bytes("lobes.npz", npz_bytes(lobes.arrays()), "application/x-npz")

    ctx.progress(0.8, "preview")
    surface = Surface(normals, params.surface.distribution_for(ctx.sub_seed("glint/surface")))
    explicit = export_normal_map(surface, PREVIEW_EXAMPLES * n)
    kind = getattr(params.example, "procedural", "normal map")
    title = f"generate.glint: {kind}, sigma_r {params.sigma_r:g}, R {res}, e {extent:g}"
    ctx.put_bytes("preview.png", preview_png(normals, explicit, maps, extent, title), "image/png")

    ours = map_bytes(maps) + len(lobes) * LOBE_BYTES
    ref_side = eff.reference_resolution
    ref_bytes = ref_side * ref_side * rate * rate * LOBE_BYTES
    stats: GlintStats = {
        "example": {"size": n, "type": kind, "cropped_from": full if n != full else None},
        "levels": len(maps),
        "ndf_resolution": res,
        "extent": extent,
        "lobes": len(lobes),
        "bytes": {
            "ndf_maps": map_bytes(maps),
            "lobes": len(lobes) * LOBE_BYTES,
            "total": ours,
        },
        "reference": {
            "resolution": ref_side,
            "lobe_rate": rate,
            "lobes": ref_side * ref_side * rate * rate,
            "bytes": ref_bytes,
            "note": "Yan et al. 2016's explicit map: one lobe record per seed",
        },
        "memory_ratio": ours / ref_bytes,
        "note": "precompute_seconds is in the job's manifest (timings.measured): timings "
        "vary from run to run",
    }
    # A timing: in the manifest, not in stats.json (same spec, same bytes).
    ctx.measure("precompute_seconds", round(seconds, 4))
    ctx.put_json("stats.json", stats)
    ctx.progress(
        1.0,
        f"{len(maps)} levels of {res}x{res} NDF images in {seconds:.2f} s; "
        f"{ours / 2**20:.2f} MiB, {100 * ours / ref_bytes:.2f} % of a {ref_side}^2 reference",
    )


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``stats.json``, one row (the example) with its memory against the
    reference (and the precompute time of a job made before timings moved to the manifest,
    ``timings.measured.precompute_seconds``, where result rows read it)."""
    doc = read_typed(read("stats.json"), GlintStats)
    if doc is None:
        return None
    row: dict[str, Any] = {
        "size": doc["example"]["size"],
        "levels": doc["levels"],
        "ndf_resolution": doc["ndf_resolution"],
        "lobes": doc["lobes"],
        "bytes": doc["bytes"]["total"],
        "reference_bytes": doc["reference"]["bytes"],
        "memory_ratio": doc["memory_ratio"],
    }
    if "precompute_seconds" in doc:
        row["precompute_seconds"] = doc["precompute_seconds"]
    return ResultTable(
        title="Tiny example", label_header="Example", columns=list(row),
        rows={doc["example"]["type"]: row}, ranked=False,
    )  # fmt: skip


register(
    Kind(
        name="generate.glint",
        params=GlintGenParams,
        runner=run_generate_glint,
        description="Tiny-example glint data (Xing et al. 2024, Sec. 5): a procedural or "
        "uploaded normal-map example, its 4D Gaussian lobes and multi-scale NDF maps (Eq. 2).",
        artifacts=("example.exr", "ndf.npz", "lobes.npz", "preview.png", "stats.json"),
        figures=(
            Figure(
                "preview.png",
                caption="The example, the preview surface and one NDF image per level.",
                lead=True,
            ),
        ),
        smoke={"example": {"procedural": "isotropic_noise", "size": 8}, "ndf_resolution": 16},
        summary=summarize,
        rows=glint_rows(summarize),
        metrics=("bytes", "reference_bytes", "memory_ratio", "precompute_seconds"),
        documents={"stats.json": GlintStats},
        layout=LAYOUT,
    )
)
