"""The ``generate.fabric`` job kind: the woven-fabric training set of Chen et al. 2024, Sec. 5.1.

Materials. For each weave pattern, ``texture_sets`` draws of the yarn geometry (twist
``psi`` and inclination ``u``, warp and weft apart), and for each of those ``shading_sets``
draws of the roughness ``alpha``, the height scaling ``beta``, the Lambertian weight ``w``
and the albedos; all from :data:`materials.fabric.params.PARAM_RANGES` (documented there:
psi U(-40, 40) deg, u U(10, 45) deg, alpha U(0.1, 0.8), beta U(0.1, 1.0), w U(0.3, 1.0),
albedos U(0.05, 0.9), gap fixed at 0.2). The paper's set is 9 x 9 = 81 plain materials and
4 x 16 = 64 for each of the three twills and three satins: 192 twill, 192 satin. The
``unseen*`` presets add the unseen twill 4x4 and give each material a ``split``
(:func:`~generators.fabric.params.material_split`: ``train``, ``unseen_material``,
``unseen_pattern``) that ``train.fabric`` trains and reports by.

Queries: the stratified design of :mod:`generators.fabric.queries` (8 x 8 centres, 10 + 10
sizes, 8 x 8 x 8 x 8 direction strata, BRDF and BTDF pairs), or with ``scene`` the queries
a render of that scene asks (:mod:`generators.fabric.scene_queries`: pixel-footprint sizes,
views from its camera, lights from its emitters). Estimation:
:func:`materials.fabric.aggregate.estimate` with ``samples`` footprint samples per query,
``sampler`` independent or scrambled Sobol (4 replicates; seeded), and standard errors.

Artifacts:

- ``shard-XXXX.npz``: ``shard_queries`` queries of one material; arrays ``material`` (N,)
  int32 (index into ``materials.json``), ``center`` (N, 2), ``size`` (N,), ``wi`` (N, 3),
  ``wo`` (N, 3), ``value`` (N, 4), ``stderr`` (N, 4), all float32 but ``material``;
  components in the order C_warp, C_weft, S_warp, S_weft (Eq. 7, unit albedos, incident
  cosine included); footprints in tile units; directions in the macro frame, z up.
- ``materials.json``: every material's parameters, seeds, maps and shards (and ``split``
  with the ``unseen*`` presets).
- ``maps/<name>-normal.exr`` and ``maps/<name>-orientation.exr``: ply normal n_p and ply
  orientation t_p over one tile (``map_resolution`` squared, xyz in RGB, row 0 at the top,
  i.e. the highest ``t``), from :func:`materials.fabric.yarn.rasterize`.
- ``preview.png``: as Fig. 2, the four components (columns) over the tile at a small
  footprint (1/32 tile) for one light/view pair, one row per pattern (its first material).
- ``stats.json``: materials, queries and samples. Every artifact is byte-deterministic for
  a spec; the throughput (seconds, samples per second) is a timing, so it is not an artifact
  but the job manifest's ``timings.measured.throughput``.

Parallelism and resumption: one shard per ``shard_queries`` queries of a material, through
``ctx.map_artifact_shards`` in batches; a shard returns its finished ``.npz`` bytes, stored
once as its artifact (which is also its shard record), so a crash loses at most the shards
in flight, and memory holds one batch at a time. Progress: per material
while the maps are written (0 - 0.02), per finished shard in every batch (0.02 - 0.95),
then the preview; each report also honours a cancel.

Modules: the params model, presets and material plan are in :mod:`generators.fabric.params`
(re-exported here), the query designs in :mod:`generators.fabric.queries` and
:mod:`generators.fabric.scene_queries`, the pictures in
:mod:`generators.fabric.preview`, the shard function in :mod:`generators.fabric.shards`;
this module draws the materials (:func:`plan_materials`) and holds the runner, its steps
and the kind's registration.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from generators.fabric.params import (
    MAX_MATERIALS,
    MAX_QUERIES,
    PRESETS,
    REPLICATES,
    SPLITS,
    FabricGenParams,
    FabricPreset,
    PresetName,
    Resolved,
    material_split,
    plan_sets,
    scene_record,
    sweep_beta,
)
from generators.fabric.preview import (
    _PREVIEW_WI,
    _PREVIEW_WO,
    PREVIEW_ROWS,
    PREVIEW_SAMPLES,
    PREVIEW_SIZE,
    map_images,
    preview_png,
)
from generators.fabric.rows import fabric_stats_rows
from generators.fabric.shards import ShardTask, estimate_shard, estimate_shards
from jobapi.documents import read_typed
from jobapi.kinds import Figure, Kind, register
from jobapi.results import ArtifactReader, ResultTable
from materials.fabric.params import FabricParams, YarnPair, sample_params
from storage.formats.fabric_documents import FabricMaterials, FabricStats

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Shards handed to the executor per ``map_artifact_shards`` call (bounds the items held).
BATCH_SHARDS = 32

#: The params model, presets and plan live in :mod:`generators.fabric.params`; they are
#: re-exported so ``from generators.fabric.kind import FabricGenParams`` (etc.) keeps working.
__all__ = [
    "BATCH_SHARDS",
    "MAX_MATERIALS",
    "MAX_QUERIES",
    "PRESETS",
    "REPLICATES",
    "FabricGenParams",
    "FabricPreset",
    "PlannedFabric",
    "PresetName",
    "Resolved",
    "SPLITS",
    "ShardTask",
    "estimate_shard",
    "params_record",
    "plan_materials",
    "plan_sets",
    "run_generate_fabric",
]


@dataclass(frozen=True)
class PlannedFabric:
    """One material: its name, place in the plan, parameters, design seed and query set.

    ``query_set`` names the seeds of the material's queries and footprint samples: the
    material's own name, or with the ``beta`` preset its pattern and texture set, so every
    beta of a texture set is estimated at the same queries with the same samples.
    """

    name: str
    pattern: str
    texture_set: int
    shading_set: int
    params: FabricParams
    design_seed: int
    query_set: str
    split: str | None = None
    """``train``, ``unseen_material`` or ``unseen_pattern`` with the ``unseen*`` presets
    (:func:`~generators.fabric.params.material_split`); ``None`` otherwise."""


def plan_materials(cfg: Resolved, ctx: JobContext) -> list[PlannedFabric]:
    """Draw every material (seeded per pattern and set, so adding one leaves others).

    With ``beta_sweep`` (the ``beta`` preset) the materials of one texture set share one
    query set: the same design seed (centres, sizes, directions) and the same footprint
    sample seeds (common random numbers), so a difference between two betas is a paired
    difference, query by query. Otherwise each material has its own.
    """
    out = []
    for name, j, k in plan_sets(cfg):
        geometry = sample_params(ctx.rng(f"generate.fabric/{name}/texture/{j}"), name)
        if cfg.beta_sweep:
            # one shading draw per texture set; only beta differs (generators.fabric.params)
            shading = sample_params(ctx.rng(f"generate.fabric/{name}/shading/{j}/0"), name)
            b = sweep_beta(k, cfg.shading_sets[name])
            shading = shading.replace(beta=YarnPair(b, b))
        else:
            shading = sample_params(ctx.rng(f"generate.fabric/{name}/shading/{j}/{k}"), name)
        params = shading.replace(
            psi_deg=geometry.psi_deg, u_max_deg=geometry.u_max_deg, yarn_profile=cfg.yarn_profile
        )
        label = f"{name}-t{j:02d}-s{k:02d}"
        query_set = f"{name}-t{j:02d}" if cfg.beta_sweep else label
        seed = ctx.sub_seed(f"generate.fabric/queries/{query_set}")
        split = material_split(name, k, cfg.shading_sets[name]) if cfg.splits else None
        out.append(PlannedFabric(label, name, j, k, params, seed, query_set, split))
    return out


def params_record(p: FabricParams) -> dict[str, Any]:
    """Every parameter of a material as plain JSON data (pairs are ``[warp, weft]``;
    ``yarn_profile`` only when not the default, so older datasets keep their bytes)."""
    rec: dict[str, Any] = {
        "pattern": p.pattern.name,
        "psi_deg": list(p.psi_deg),
        "u_max_deg": list(p.u_max_deg),
        "alpha": list(p.alpha),
        "beta": list(p.beta),
        "w": p.w,
        "kd_warp": list(p.kd_warp),
        "kd_weft": list(p.kd_weft),
        "ks_warp": list(p.ks_warp),
        "ks_weft": list(p.ks_weft),
        "gap": p.gap,
        "t_rho": p.t_rho,
    }
    if p.yarn_profile != "smooth":
        rec["yarn_profile"] = p.yarn_profile
    return rec


def _config_doc(cfg: Resolved) -> dict[str, Any]:
    """``materials.json``'s ``config``; ``sizes`` only when not the paper's strata and
    ``scene`` only when set (so a default job's ``materials.json`` keeps its bytes); with a
    scene, no ``btdf_fraction`` (the scene's lights decide the side)."""
    doc = {**cfg.__dict__, "patterns": list(cfg.patterns), "replicates": REPLICATES}
    if doc["sizes"] == "strata":
        del doc["sizes"]
    if doc["yarn_profile"] == "smooth":
        del doc["yarn_profile"]
    if not doc["splits"]:
        del doc["splits"]
    if cfg.scene is None:
        del doc["scene"]
    else:
        doc["scene"] = scene_record(cfg.scene)
        del doc["btdf_fraction"]
    return doc


def run_generate_fabric(params: FabricGenParams, ctx: JobContext) -> None:
    """Plan materials, write their maps, estimate every shard, then preview and stats."""
    started = time.perf_counter()
    cfg = params.resolved()
    ctx.progress(0.0, "planning materials")
    planned = plan_materials(cfg, ctx)
    tasks, owners = _shard_tasks(cfg, planned, ctx)
    records = _write_maps(cfg, planned, owners, ctx)
    ctx.progress(0.02, f"{len(planned)} material(s), {len(tasks)} shard(s)")
    estimate_shards(tasks, BATCH_SHARDS, ctx)
    ctx.progress(0.95, "preview")
    previewed = _write_preview(planned, ctx)
    _write_materials_doc(params, cfg, records, previewed, ctx)
    _write_stats(cfg, planned, started, ctx)


def _shard_tasks(
    cfg: Resolved, planned: list[PlannedFabric], ctx: JobContext
) -> tuple[list[ShardTask], list[list[str]]]:
    """Every shard's task, numbered across materials, and each material's shard names."""
    tasks: list[ShardTask] = []
    owners: list[list[str]] = []
    for i, m in enumerate(planned):
        names = []
        for first in range(0, cfg.queries, cfg.shard_queries):
            names.append(f"shard-{len(tasks):04d}.npz")
            tasks.append(
                ShardTask(
                    material=i,
                    params=m.params,
                    design_seed=m.design_seed,
                    first=first,
                    count=min(cfg.shard_queries, cfg.queries - first),
                    btdf_fraction=cfg.btdf_fraction,
                    samples=cfg.samples,
                    sampler=cfg.sampler,
                    sample_seed=ctx.sub_seed(f"generate.fabric/samples/{m.query_set}/{first}"),
                    backend=cfg.backend,
                    sizes=cfg.sizes,
                    scene=cfg.scene,
                )
            )
        owners.append(names)
    return tasks, owners


def _write_maps(
    cfg: Resolved, planned: list[PlannedFabric], owners: list[list[str]], ctx: JobContext
) -> list[dict[str, Any]]:
    """Write each material's normal and orientation maps (progress 0 - 0.02); returns the
    materials' records for ``materials.json``."""
    records = []
    for i, (m, shards) in enumerate(zip(planned, owners, strict=True)):
        # Paper scale: 465 materials x ~0.1 s of maps each; report (and honour cancel).
        ctx.progress(0.02 * i / len(planned), f"maps: {i}/{len(planned)} material(s)")
        normal, orientation = map_images(m.params, cfg.map_resolution)
        maps = {
            "normal": f"maps/{m.name}-normal.exr",
            "orientation": f"maps/{m.name}-orientation.exr",
        }
        ctx.put_bytes(maps["normal"], normal, "image/x-exr")
        ctx.put_bytes(maps["orientation"], orientation, "image/x-exr")
        record: dict[str, Any] = {
            "name": m.name,
            "pattern": m.pattern,
            "texture_set": m.texture_set,
            "shading_set": m.shading_set,
            "params": params_record(m.params),
            "design_seed": m.design_seed,
            "maps": maps,
            "shards": shards,
        }
        if m.split is not None:  # only with the unseen* presets: older datasets keep bytes
            record["split"] = m.split
        records.append(record)
    return records


def _write_preview(planned: list[PlannedFabric], ctx: JobContext) -> list[PlannedFabric]:
    """Write ``preview.png`` (each pattern's first material, up to :data:`PREVIEW_ROWS`);
    returns the materials shown."""
    first_of_pattern = [m for m in planned if m.texture_set == 0 and m.shading_set == 0]
    shown = first_of_pattern[:PREVIEW_ROWS]
    ctx.put_bytes(
        "preview.png",
        preview_png(shown, ctx.sub_seed("generate.fabric/preview")),
        "image/png",
    )
    return shown


def _write_materials_doc(
    params: FabricGenParams,
    cfg: Resolved,
    records: list[dict[str, Any]],
    previewed: list[PlannedFabric],
    ctx: JobContext,
) -> None:
    """Write ``materials.json``: the materials' records, the config and the preview's
    materials and directions."""
    ctx.put_json(
        "materials.json",
        {
            "materials": records,
            "components": ["C_warp", "C_weft", "S_warp", "S_weft"],
            "preset": params.preset,
            "config": _config_doc(cfg),
            "preview": {
                "materials": [m.name for m in previewed],
                "footprint_size": PREVIEW_SIZE,
                "wi": _PREVIEW_WI.tolist(),
                "wo": _PREVIEW_WO.tolist(),
                "samples": PREVIEW_SAMPLES,
            },
        },
    )


def _write_stats(
    cfg: Resolved, planned: list[PlannedFabric], started: float, ctx: JobContext
) -> None:
    """Write ``stats.json`` (counts only), measure the throughput since ``started`` (a
    ``time.perf_counter()``) into the manifest, and report the end (progress 1)."""
    seconds = time.perf_counter() - started
    samples = len(planned) * cfg.queries * cfg.samples
    # The throughput is a timing: in the manifest (timings.measured.throughput), not in
    # stats.json, whose bytes are the same for the same spec.
    ctx.measure(
        "throughput",
        {
            "seconds": round(seconds, 3),
            "samples_per_second": round(samples / max(seconds, 1e-9), 1),
        },
    )
    ctx.put_json(
        "stats.json",
        {
            "materials": len(planned),
            "queries": len(planned) * cfg.queries,
            "samples_per_query": cfg.samples,
            "samples": samples,
            "backend": cfg.backend,
            "note": "seconds and samples per second are in the job's manifest "
            "(timings.measured.throughput): timings vary from run to run",
        },
    )
    ctx.progress(
        1.0,
        f"{len(planned)} material(s), {samples:.3g} samples in {seconds:.1f} s "
        f"({samples / max(seconds, 1e-9):.3g} samples/s)",
    )


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``materials.json``, one row per material (pattern, sets, shards),
    with the counts of ``stats.json`` in the settings (the throughput is in the manifest,
    ``timings.measured.throughput``; a job made before it moved there has it here)."""
    doc = read_typed(read("materials.json"), FabricMaterials)
    if doc is None or not doc["materials"]:
        return None
    columns = ["pattern", "texture_set", "shading_set", "shards"]
    rows: dict[str, dict[str, Any]] = {
        m["name"]: {
            "pattern": m["pattern"],
            "texture_set": m["texture_set"],
            "shading_set": m["shading_set"],
            "shards": len(m["shards"]),
        }
        for m in doc["materials"]
    }
    if any("split" in m for m in doc["materials"]):  # the unseen* presets' held-out sets
        columns.append("split")
        for m in doc["materials"]:
            rows[m["name"]]["split"] = m.get("split")
    return ResultTable(
        title="Materials",
        label_header="Material",
        columns=columns,
        rows=rows,
        ranked=False,  # a dataset's materials: measured, none is "the best"
        settings={"config": doc["config"], "stats": read("stats.json")},
    )


def _estimated_by_drjit(params: FabricGenParams) -> bool:
    """Whether the estimator is the fused Dr.Jit kernel (its bytes depend on the variant),
    not the numpy reference."""
    return params.backend == "drjit"


register(
    Kind(
        name="generate.fabric",
        variant_bytes=_estimated_by_drjit,
        params=FabricGenParams,
        runner=run_generate_fabric,
        description="Woven-fabric training set (Chen et al. 2024, Sec. 5.1): aggregated BSDF "
        "components C/S warp/weft with standard errors at stratified footprint queries.",
        artifacts=("shard-*.npz", "materials.json", "maps/*.exr", "stats.json", "preview.png"),
        documents={"materials.json": FabricMaterials, "stats.json": FabricStats},
        figures=(
            Figure(
                "preview.png",
                caption="As Fig. 2 of Chen et al.: C and S, warp and weft (columns) over one "
                "tile, one row per pattern.",
                lead=True,
            ),
        ),
        smoke={
            "patterns": ["plain"],
            "queries_per_material": 64,
            "samples": 64,
            "map_resolution": 16,
            "backend": "numpy",
        },
        summary=summarize,
        rows=fabric_stats_rows,
        metrics=("samples_per_second", "seconds"),
    )
)
