"""``select`` over a scene: render each rung, score it against the reference, choose.

The second mode of the ``select`` kind (:mod:`evaluators.report.select` documents both).
Given a scene (a ``render`` spec without its material), a reference (an image ref, or a
material to path-trace at high spp) and a ladder of candidate materials, every rung and the
reference are rendered as shards through the job's executor (``ctx.map_shards``: the local
process pool, or Ray with ``MATFORGE_EXECUTOR=ray``); a job that crashed resumes from the
shards it recorded. Each rung is scored against the reference with the ``score`` kind's
conventions and :mod:`evaluators.metrics.images` (HDR-FLIP with the exposure range derived
once from the reference, PSNR and SSIM over the reference's maximum).

Shards run where the job's context is not (another process or node), so a rung's material
is resolved once here with a context that records what it reads (artifact bytes, input
jobs); the shard replays those records (:class:`ReplayContext`). Resolving here also fails
a bad material before any render is queued.

Cost: ``render_seconds`` is the shard's own wall time for that rung (scene load, kernel
compilation, passes; measured in the shard, so it varies with the machine's load);
``frame_seconds`` the rung's frame time once its kernels are compiled, what a renderer pays
per frame: the passes after the first, per sample, times the rung's samples (the first pass
compiles; a rung of one pass, below 2^22 paths, has only that pass, compile included);
``spp`` the rung's samples; ``ns_per_eval`` is timed here, every rung's model and the
reference kernel in one pass (:mod:`evaluators.report.timing`), with its spread and its
ratio to the reference; ``bytes_per_material`` and ``bytes_per_network`` come from the
result rows of the ``train.*`` job a ``{"model": "job:<id>/..."}`` rung names, and for an
``{"external": ...}`` rung (a user's model) ``bytes_per_network`` is measured here as
``score`` measures it (:mod:`models.external.cost`). Each rung names its ``runtime``.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from evaluators.metrics.images import flip, hdr_exposure_range, mae, mse, psnr, ssim
from evaluators.metrics.tonemap import magma, tonemap
from evaluators.render.kind import PATHS_PER_PASS, RenderParams, load_scene, plan_passes
from evaluators.render.sources import resolve_material
from evaluators.report.timing import pass_cost
from jobapi.errors import JobFailed
from jobapi.params import JOB_REF
from storage.errors import FormatError
from storage.formats.exr import exr_bytes, read_exr
from storage.formats.png import write_png

if TYPE_CHECKING:
    from evaluators.report.select import SelectLadder
    from evaluators.report.select_params import Rung, SelectParams
    from jobapi.context import JobContext
    from storage.job_records import Job

#: SSIM window, as the ``score`` kind (:data:`evaluators.score.images.SSIM_WINDOW`).
SSIM_WINDOW = 7
#: Costs read from the model job a rung names (its result rows), not measured here.
MODEL_COSTS = ("ns_per_eval", "bytes_per_material", "bytes_per_network")
REFERENCE = "reference"


# -- resolving a material where the job's context is not ---------------------------------


@dataclass
class Recorded:
    """What a material's resolver read through the job's context (picklable)."""

    job_id: str
    seed: int
    blobs: dict[str, bytes] = field(default_factory=dict)
    jobs: dict[str, Job] = field(default_factory=dict)


class RecordingContext:
    """Delegates the reads a material resolver makes to ``ctx`` and records them."""

    def __init__(self, ctx: JobContext) -> None:
        self._ctx = ctx
        self.job_id = ctx.job_id
        self.seed = ctx.seed
        self.record = Recorded(job_id=ctx.job_id, seed=ctx.seed)

    def resolve(self, ref: str) -> Path:
        path = self._ctx.resolve(ref)
        self.record.blobs[ref] = path.read_bytes()
        return path

    def read_ref(self, ref: str) -> bytes:
        data = self._ctx.read_ref(ref)
        self.record.blobs[ref] = data
        return data

    def input_job(self, job_id: str, field: str, kind: str | None = None) -> Job:
        job = self._ctx.input_job(job_id, field, kind)
        self.record.jobs[job_id] = job
        return job

    def sub_seed(self, stream: int | str) -> int:
        return self._ctx.sub_seed(stream)

    def rng(self, stream: int | str = 0) -> np.random.Generator:
        return self._ctx.rng(stream)

    def check_cancelled(self) -> None:
        self._ctx.check_cancelled()


class ReplayContext:
    """Serves a :class:`Recorded` in a shard: ``resolve`` writes the bytes to a scratch
    file (removed by :meth:`close`); a read that was not recorded fails the job."""

    def __init__(self, record: Recorded) -> None:
        self.record = record
        self.job_id = record.job_id
        self.seed = record.seed
        self._dir: Path | None = None

    def _missing(self, ref: str) -> JobFailed:
        return JobFailed(f"material: {ref} was not read when the material was checked")

    def resolve(self, ref: str) -> Path:
        if ref not in self.record.blobs:
            raise self._missing(ref)
        if self._dir is None:
            self._dir = Path(tempfile.mkdtemp(prefix="matforge-select-"))
        path = self._dir / f"{len(list(self._dir.iterdir())):04d}"
        path.write_bytes(self.record.blobs[ref])
        return path

    def read_ref(self, ref: str) -> bytes:
        if ref not in self.record.blobs:
            raise self._missing(ref)
        return self.record.blobs[ref]

    def input_job(self, job_id: str, field: str, kind: str | None = None) -> Job:
        if job_id not in self.record.jobs:
            raise JobFailed(f"{field}: job {job_id} was not read when the material was checked")
        return self.record.jobs[job_id]

    def sub_seed(self, stream: int | str) -> int:
        return int(self.rng(stream).integers(0, 2**31 - 1))

    def rng(self, stream: int | str = 0) -> np.random.Generator:
        import hashlib

        tag = (
            stream
            if isinstance(stream, int)
            else int.from_bytes(hashlib.sha256(str(stream).encode()).digest()[:8], "little")
        )
        return np.random.default_rng(np.random.SeedSequence([self.seed, tag]))

    def check_cancelled(self) -> None:
        pass

    def close(self) -> None:
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None


# -- the shard ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RungTask:
    """One render of the ladder (or the reference): a picklable shard item."""

    name: str
    render: dict[str, Any]  # RenderParams as JSON, material included
    seeds: tuple[int, ...]
    record: Recorded


def render_rung(task: RungTask) -> dict[str, Any]:
    """Render one rung (module level: the executor pickles it). Returns ``{"image":
    (H, W, 3) float32 linear RGB, "seconds": wall seconds of scene load and passes,
    "frame_seconds": the frame time with compiled kernels (see the module), "integrator":
    name, "passes": [spp, ...]}``."""
    from evaluators.render.kind import render_passes
    from materials.backend import load_mitsuba

    params = RenderParams.model_validate(task.render)
    width, height = params.resolution
    passes = plan_passes(width, height, params.spp, PATHS_PER_PASS)
    mi = load_mitsuba()
    replay = ReplayContext(task.record)
    try:
        started = time.perf_counter()
        bsdf = resolve_material(params.material, replay, mi)  # type: ignore[arg-type]
        scene, scene_dict, _ = load_scene(params, bsdf, mi, passes[0])
        marks = [time.perf_counter()]
        image = render_passes(
            mi,
            scene,
            passes,
            list(task.seeds),
            on_pass=lambda *_: marks.append(time.perf_counter()),
        )
        seconds = marks[-1] - started
    finally:
        replay.close()
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise JobFailed(f"{task.name}: the render has {bad} non-finite pixel values")
    return {
        "image": image,
        "seconds": seconds,
        "frame_seconds": frame_seconds(passes, marks),
        "integrator": str(scene_dict["integrator"]["type"]),
        "passes": passes,
    }


def frame_seconds(passes: list[int], marks: list[float]) -> float:
    """The frame time of a render of ``passes`` (spp each) with compiled kernels, from
    ``marks``: the clock before the first pass and after each. The passes after the first
    are timed per sample and scaled to all of them; with one pass, its own time."""
    if len(marks) != len(passes) + 1:
        raise ValueError(f"{len(marks)} marks for {len(passes)} passes")
    if len(passes) == 1:
        return marks[1] - marks[0]
    return (marks[-1] - marks[1]) / sum(passes[1:]) * sum(passes)


# -- scoring -----------------------------------------------------------------------------


def image_metric(metric: str, reference: np.ndarray, image: np.ndarray) -> tuple[float, Any]:
    """``metric`` of ``image`` against ``reference`` (both ``(H, W, 3)`` linear RGB) as the
    ``score`` kind computes it for EXR images; returns ``(value, FLIP error map or None)``."""
    data_range = float(reference.max())
    if data_range <= 0.0:
        raise JobFailed("reference: the image is black; the metrics need some light")
    if metric == "flip":
        exposure = hdr_exposure_range(reference, tonemapper="aces")
        value, error_map = flip(reference, image, mode="hdr", exposure_range=exposure)
        return float(value), error_map
    if metric == "psnr":
        return float(psnr(reference, image, data_range=data_range)), None
    if metric == "ssim":
        return float(ssim(reference, image, data_range=data_range, win_size=SSIM_WINDOW)), None
    if metric == "mae":
        return float(mae(reference, image)), None
    if metric == "mse":
        return float(mse(reference, image)), None
    raise JobFailed(f"metric: {metric!r} is not an image metric")


def rung_runtime(rung: Rung, ctx: JobContext) -> str:
    """What evaluates the rung's material: an external model's runtime, ``drjit-fused`` for
    a trained model, ``mitsuba`` for every other material (tables, Mitsuba plugins)."""
    value = rung.material.get("external")
    if isinstance(value, dict):
        from models.external import load_external

        try:
            model = load_external(
                ctx.resolve(value["model"]), value["kind"], runtime=value.get("runtime")
            )
            return str(model.runtime)
        except (ValueError, FormatError):
            return "external"
    return "drjit-fused" if "model" in rung.material else "mitsuba"


def external_cost(rung: Rung, cost: str, index: int, ctx: JobContext) -> float:
    """``cost`` (``ns_per_eval`` or ``bytes_per_network``) of an ``{"external": ...}`` rung,
    measured here as ``score`` measures it (:func:`models.external.cost.measure_cost`)."""
    from models.external import load_external
    from models.external.cost import measure_cost

    value = rung.material["external"]
    where = f"ladder.{index}.material.external"
    try:
        model = load_external(
            ctx.resolve(value["model"]),
            value["kind"],
            label=value["model"],
            runtime=value.get("runtime"),
        )
        measured = measure_cost(model)
    except (ValueError, FormatError) as exc:
        raise JobFailed(f"{where}: {value['model']}: {exc}") from None
    if measured.get(cost) is None:
        raise JobFailed(f"{where}: an external model has no {cost}")
    return float(measured[cost])


def model_cost(rung: Rung, cost: str, index: int, ctx: JobContext) -> float:
    """``cost`` of a ``{"model": "job:<id>/..."}`` rung, from that job's result rows (of an
    ``{"external": ...}`` rung, measured: :func:`external_cost`)."""
    if "external" in rung.material:
        return external_cost(rung, cost, index, ctx)
    from jobapi.kinds import registered
    from jobapi.row_sources import StoreSource

    where = f"ladder.{index}.material.model"
    ref = rung.material.get("model")
    m = JOB_REF.match(ref) if isinstance(ref, str) else None
    if m is None:
        raise JobFailed(f"{where}: cost {cost} is read from the model's job: give 'job:<id>/...'")
    job = ctx.input_job(m["job"], where)
    kind = registered().get(job.kind)
    rows = kind.rows(StoreSource(job, ctx.jobs, ctx.store)) if kind and kind.rows else []
    name = rung.material.get("material")
    values = [
        getattr(r, cost)
        for r in rows
        if getattr(r, cost) is not None and (name is None or r.material in (None, name))
    ]
    if not values:
        raise JobFailed(f"{where}: job {job.id} ({job.kind}) has no {cost} for this material")
    return float(np.median(values))


# -- the runner --------------------------------------------------------------------------


def run_scene_select(params: SelectParams, ctx: JobContext) -> dict[str, Any]:
    """Render, score and choose; writes the rung images and returns ``select.json``'s
    document less the chart (the caller, :func:`evaluators.report.select.run_select`,
    writes it and the chart)."""
    from evaluators.report.timing import timing_summary
    from jobapi.rows import lower_is_better

    assert params.scene is not None and params.reference is not None and params.ladder
    scene = params.scene.model_dump(mode="json", exclude={"material"})
    tasks = rung_tasks(params, scene, ctx)
    results = ctx.map_shards(
        render_rung,
        tasks,
        keys=[f"render-{t.name}" for t in tasks],
        label="render",
        progress_range=(0.02, 0.9),
    )
    by_name = dict(zip([t.name for t in tasks], results, strict=True))
    reference, dataset = reference_image(params, by_name, ctx)
    timing = rung_timing(params, ctx)
    points = score_rungs(params, reference, by_name, ctx, timing)
    lower = lower_is_better(params.metric) is not False
    timed: dict[str, Any] = {} if timing is None else {"timing": timing_summary(timing)}
    return {
        **timed,
        "mode": "scene",
        "scene": scene,
        "reference": params.reference
        if isinstance(params.reference, str)
        else params.reference.model_dump(mode="json"),
        "ladder": [r.model_dump(mode="json") for r in params.ladder],
        "lower_is_better": lower,
        "ladders": [choose(params, dataset, points, lower)],
    }


def rung_tasks(params: SelectParams, scene: dict[str, Any], ctx: JobContext) -> list[RungTask]:
    """One render shard per rung, and one for the reference when it is a material to
    render: each material resolved here (failing a bad one before any render is queued,
    naming ``reference`` or ``ladder.<i>``), with what its resolver read recorded."""
    from materials.backend import load_mitsuba

    assert params.scene is not None and params.reference is not None and params.ladder
    renders: list[tuple[str, dict[str, Any]]] = []
    if not isinstance(params.reference, str):
        ref = params.reference
        renders.append((REFERENCE, {**scene, "material": ref.material, "spp": ref.spp}))
    for rung in params.ladder:
        spp = rung.spp if rung.spp is not None else params.scene.spp
        renders.append((rung.name, {**scene, "material": rung.material, "spp": spp}))

    ctx.progress(0.0, f"checking {len(renders)} materials")
    mi = load_mitsuba()
    tasks = []
    offset = len(renders) - len(params.ladder)  # 1 when the reference is rendered here
    for i, (name, spec) in enumerate(renders):
        recorder = RecordingContext(ctx)
        where = "reference" if i < offset else f"ladder.{i - offset}"
        try:
            resolve_material(spec["material"], recorder, mi)  # type: ignore[arg-type]
        except JobFailed as exc:
            raise JobFailed(f"{where}.{exc}") from None
        rp = RenderParams.model_validate(spec)
        n_passes = len(plan_passes(rp.resolution[0], rp.resolution[1], rp.spp, PATHS_PER_PASS))
        # Seeds per rung name: a rung renders the same image wherever it sits in the ladder.
        seeds = tuple(ctx.sub_seed(f"select/{name}/pass/{k}") for k in range(n_passes))
        tasks.append(RungTask(name=name, render=spec, seeds=seeds, record=recorder.record))
    return tasks


def reference_image(
    params: SelectParams, by_name: dict[str, dict[str, Any]], ctx: JobContext
) -> tuple[np.ndarray, str]:
    """The reference image (RGB, float32) and the ladder's dataset: the image ref as given,
    or the rendered reference, written as ``reference.exr``/``.png`` and named by its
    content."""
    assert params.scene is not None and params.reference is not None
    if isinstance(params.reference, str):
        try:
            reference = read_exr(ctx.resolve(params.reference), params.reference)
        except FormatError as exc:
            raise JobFailed(f"reference: {exc}") from None
        if reference.shape[:2] != (params.scene.resolution[1], params.scene.resolution[0]):
            raise JobFailed(
                f"reference: size {reference.shape[1]}x{reference.shape[0]} differs from the "
                f"scene's {params.scene.resolution[0]}x{params.scene.resolution[1]}"
            )
        return np.asarray(reference[..., :3], dtype=np.float32), params.reference
    reference = by_name[REFERENCE]["image"]
    rec = ctx.put_bytes("reference.exr", exr_bytes(reference), "image/x-exr")
    ctx.put_bytes("reference.png", write_png(None, tonemap(reference)), "image/png")
    # The ladder's dataset is the reference image by content: the same for the same
    # render, and distinct from any other select's reference in report.pareto.
    return reference, f"sha256:{rec.digest}"


def shard_frame_seconds(got: dict[str, Any]) -> float:
    """A rung shard's frame time; a shard recorded before frame_seconds existed has only
    its wall time."""
    return float(got.get("frame_seconds", got["seconds"]))


def rung_cost(
    params: SelectParams, rung: Rung, index: int, got: dict[str, Any], ctx: JobContext
) -> float:
    """The rung's cost, ``params.cost``: measured by its shard, its spp, or read from (or
    measured for) the model it names."""
    assert params.scene is not None
    if params.cost == "render_seconds":
        return float(got["seconds"])
    if params.cost == "frame_seconds":
        return shard_frame_seconds(got)
    if params.cost == "spp":
        return float(rung.spp if rung.spp is not None else params.scene.spp)
    return model_cost(rung, params.cost, index, ctx)


def rung_timing(params: SelectParams, ctx: JobContext) -> dict[str, Any] | None:
    """By ``ns_per_eval``: every rung's model (each is one, as the params require) and the
    reference kernel timed in one pass (:func:`evaluators.report.timing.comparison_pass`);
    else ``None``."""
    from evaluators.report.timing import PASS_COSTS, comparison_pass, material_target

    if params.cost not in PASS_COSTS:
        return None
    assert params.ladder
    targets = {}
    for i, rung in enumerate(params.ladder):
        target = material_target(rung.material)
        if target is None:
            raise JobFailed(f"ladder.{i}.material: no model to time for cost {params.cost}")
        targets[rung.name] = target
    ctx.progress(0.9, f"timing {len(targets)} rungs and the reference kernel in one pass")
    record = comparison_pass(targets, params.timing, ctx)
    ctx.measure("timing", record)
    return record


def score_rungs(
    params: SelectParams,
    reference: np.ndarray,
    by_name: dict[str, dict[str, Any]],
    ctx: JobContext,
    timing: dict[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """Each rung scored against ``reference``, its images written (``rung_<name>.exr`` and
    ``.png``, and ``flip_<name>.png`` for a metric with an error map); one point each."""
    assert params.scene is not None and params.ladder
    points = []
    for i, rung in enumerate(params.ladder):
        got = by_name[rung.name]
        value, error_map = image_metric(params.metric.removeprefix("image."), reference,
                                        got["image"])  # fmt: skip
        ctx.put_bytes(f"rung_{rung.name}.exr", exr_bytes(got["image"]), "image/x-exr")
        ctx.put_bytes(f"rung_{rung.name}.png", write_png(None, tonemap(got["image"])), "image/png")
        if error_map is not None:
            ctx.put_bytes(f"flip_{rung.name}.png", write_png(None, magma(error_map)), "image/png")
        spp = rung.spp if rung.spp is not None else params.scene.spp
        frame = shard_frame_seconds(got)
        timed = pass_cost(timing, rung.name) if timing is not None else None
        points.append(
            {
                "candidate": rung.name,
                "mean": value,
                "n": 1,
                "min": value,
                "max": value,
                "cost": timed["cost"] if timed else rung_cost(params, rung, i, got, ctx),
                "spp": spp,
                "render_seconds": float(got["seconds"]),
                "frame_seconds": frame,
                "integrator": got["integrator"],
                "material": rung.material,
                "runtime": rung_runtime(rung, ctx),
                **(
                    {k: timed[k] for k in ("cost_min", "cost_max", "cost_n", "relative")}
                    if timed
                    else {}
                ),  # fmt: skip
            }
        )
        ctx.progress(0.9 + 0.08 * (i + 1) / len(params.ladder), f"scored {rung.name}")
    return points


def choose(
    params: SelectParams, dataset: str, points: list[dict[str, Any]], lower: bool
) -> SelectLadder:
    """The ladder of ``select.json``: the cheapest rung meeting the target
    (:func:`evaluators.report.select.ladders`), each rung with its render facts and image."""
    from evaluators.report.select import ladders

    assert params.scene is not None
    panel = {
        "dataset": dataset,
        "scene": params.scene.scene,
        "metric": params.metric,
        "cost": params.cost,
        "cost_label": params.cost,
        "points": points,
    }
    (lad,) = ladders([panel], params.target, lower)
    extra = {p["candidate"]: p for p in points}
    for r in lad["rungs"]:
        p = extra[r["candidate"]]
        r.update(
            {
                "spp": p["spp"],
                "render_seconds": p["render_seconds"],
                "frame_seconds": p["frame_seconds"],
                "integrator": p["integrator"],
                "material": p["material"],
                "image": f"rung_{r['candidate']}.exr",
            }
        )
    return lad
