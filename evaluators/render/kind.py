"""The ``render`` job kind: a path-traced reference image with Mitsuba 3.

Artifacts:

- ``image.exr``: linear Rec. 709 RGB radiance, float32, ``(height, width, 3)``;
- ``preview.png``: the same image tone-mapped for display (ACES filmic, exposure 0, sRGB;
  see :mod:`evaluators.metrics.tonemap`);
- ``render.json``: the settings as rendered (scene, camera, lights, material, passes and
  their seeds, Mitsuba version and variant).

Reproducibility: the image is the sample-count-weighted mean of several passes, each a
``mi.render`` call with its own seed derived from the job's seed (``ctx.sub_seed``). With
the box filter every pass is deterministic, so the same spec gives the same bytes; timings
are therefore kept out of the artifacts and reported in the job's final message instead.
Passes also make progress visible and let a cancellation stop a long render between them.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
import time
import types
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from evaluators.metrics.tonemap import tonemap
from evaluators.render.bsdfs.external_onnx import wavefront_scope
from evaluators.render.document import RenderDocument
from evaluators.render.integrators import integrator_for
from evaluators.render.rows import render_rows
from evaluators.render.scenes import SCENES, Camera, PointLight, SceneSetup, build_scene
from evaluators.render.sources import MaterialParam, resolve_material
from evaluators.render.sources.common import mitsuba_message
from jobapi.documents import read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.params import StrictModel
from jobapi.results import ArtifactReader, ResultTable
from materials.backend import active_variant, load_mitsuba
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png

if TYPE_CHECKING:
    from jobapi.context import JobContext

log = logging.getLogger(__name__)

#: Paths traced per ``mi.render`` pass, about 0.3 s on two cores with the LLVM variant.
PATHS_PER_PASS = 1 << 22
#: Upper bound on width * height * spp (about 80 minutes on two cores).
MAX_PATHS = 1 << 36
DEFAULT_MATERIAL: dict[str, Any] = {
    "mitsuba": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}
}
Side = Annotated[int, Field(ge=8, le=4096)]


class RenderParams(StrictModel):
    """Parameters of ``render``.

    ==============  ===================  ==============  ======================================
    name            type                 default         meaning
    ==============  ===================  ==============  ======================================
    ``scene``       built-in scene name  ``sphere_env``  ``sphere_env``, ``sphere_points``,
                                                         ``plane_points``, ``cloth_plane``
    ``material``    ``{source: value}``  grey diffuse    e.g. ``{"mitsuba": {"type":
                                         (0.5)           "roughconductor", "alpha": 0.2}}``
    ``resolution``  ``[width, height]``  ``[256, 256]``  pixels, each 8..4096
    ``spp``         int                  64              samples per pixel, 1..65536
    ``max_depth``   int                  8               longest path, in segments, 1..64
    ``lights``      list of point lights none            replaces the scene's point lights
                                                         (added to the map in ``sphere_env``)
    ``camera``      camera               none            replaces the scene's camera
    ==============  ===================  ==============  ======================================

    Example::

        {"kind": "render", "seed": 1, "params": {"scene": "sphere_env",
         "material": {"mitsuba": {"type": "roughconductor", "alpha": 0.2}},
         "resolution": [512, 512], "spp": 256}}
    """

    scene: Literal[
        "sphere_env",
        "sphere_points",
        "plane_points",
        "cloth_plane",
        "bent_quad",
        "glint_sphere",
        "glint_closeup",
    ] = Field(
        default="sphere_env",
        description="Built-in scene: 'sphere_env' (unit sphere under "
        "matforge's HDR studio environment), 'sphere_points' (the sphere under three point "
        "lights), 'plane_points' (a textured plane seen at an angle, three point lights), "
        "'cloth_plane' (a square of cloth under the studio environment and a light), "
        "'bent_quad' or 'glint_sphere' (a bent sheet or the sphere under four point lights "
        "and a dim environment, for glints), 'glint_closeup' (the bent quad's apex close up under "
        "two point lights: about 2-4 example texels per pixel at 2048 texels per uv).",
    )
    material: MaterialParam = Field(
        default_factory=lambda: copy.deepcopy(DEFAULT_MATERIAL),
        json_schema_extra={"default": DEFAULT_MATERIAL},
        description="The material on the scene's object: an object with exactly one "
        'material source key, e.g. {"mitsuba": {<Mitsuba 3 BSDF plugin dict>}}. '
        "Default: grey diffuse (reflectance 0.5); the job's message says when it was used.",
    )
    resolution: Annotated[tuple[Side, Side], Field(strict=False)] = Field(
        default=(256, 256), description="Image size [width, height] in pixels, each 8..4096."
    )
    spp: int = Field(default=64, ge=1, le=65536, description="Samples (paths) per pixel, 1..65536.")
    max_depth: int = Field(
        default=8,
        ge=1,
        le=64,
        description="Maximum path length in segments (1: emitters only, "
        "2: direct lighting), 1..64.",
    )
    lights: list[PointLight] | None = Field(
        default=None,
        max_length=16,
        description="Point lights {position [x, y, z], "
        "intensity [r, g, b] in W/sr}. Replaces the scene's point lights; in 'sphere_env' "
        "they are added to the environment map. Default: the scene's own.",
    )
    camera: Camera | None = Field(
        default=None,
        description="Camera {origin, target, up, fov (degrees, smaller image "
        "side)}, y up. Default: the scene's own.",
    )

    @model_validator(mode="after")
    def _check_budget(self) -> RenderParams:
        paths = self.resolution[0] * self.resolution[1] * self.spp
        if paths > MAX_PATHS:
            raise ValueError(
                f"width * height * spp = {paths} paths exceeds the limit of "
                f"{MAX_PATHS}; lower spp or resolution"
            )
        return self


def plan_passes(
    width: int, height: int, spp: int, paths_per_pass: int = PATHS_PER_PASS
) -> list[int]:
    """Split ``spp`` into passes of about ``paths_per_pass`` paths each.

    Returns the samples per pixel of each pass: at most two distinct values (so Mitsuba
    compiles at most two kernels), larger ones first, summing to ``spp``.
    """
    if min(width, height, spp, paths_per_pass) < 1:
        raise ValueError("plan_passes needs positive sizes")
    n = min(spp, max(1, math.ceil(width * height * spp / paths_per_pass)))
    base, extra = divmod(spp, n)
    return [base + 1] * extra + [base] * (n - extra)


def render_passes(
    mi: types.ModuleType,
    scene: Any,
    passes: list[int],
    seeds: list[int],
    on_pass: Callable[[int, int], None] | None = None,
) -> np.ndarray:
    """Render ``scene`` once per pass and return the spp-weighted mean image.

    ``passes[i]`` samples per pixel are traced with seed ``seeds[i]``. With a box filter a
    pixel is the mean of its samples, so the weighted mean of the passes is the same
    estimator as one render of ``sum(passes)`` samples (same expectation and variance).
    ``on_pass(i, samples_done)`` runs after each pass (progress; it may raise to cancel).
    Returns ``(height, width, 3)`` float32 linear RGB.
    """
    total: np.ndarray | None = None
    done = 0
    for i, (n, seed) in enumerate(zip(passes, seeds, strict=True)):
        # np.asarray reads the image back to the host: the pass has really run (Dr.Jit
        # evaluates lazily), so timings around this function are honest.
        # A model that runs outside Dr.Jit (an ONNX file) needs the evaluated (wavefront)
        # path loop: the scope turns symbolic loops and calls off while one is alive.
        with wavefront_scope():
            img = np.asarray(mi.render(scene, spp=n, seed=seed), dtype=np.float64)[..., :3]
        total = img * n if total is None else total + img * n
        done += n
        if on_pass is not None:
            on_pass(i, done)
    if total is None:
        raise ValueError("render_passes needs at least one pass")
    return (total / done).astype(np.float32)


class _Compiled:
    """Seconds Dr.Jit spent compiling kernels (code generation and the LLVM/CUDA backend)
    inside a :func:`kernel_compile_timer` block; set when the block ends."""

    seconds: float = 0.0


@contextlib.contextmanager
def kernel_compile_timer() -> Iterator[_Compiled]:
    """Time the kernel compilation of the block from Dr.Jit's kernel history (which it
    keeps only while ``JitFlag.KernelHistory`` is set; the flag is restored after). A
    kernel found in Dr.Jit's cache costs no compilation. Renders subtract this from their
    wall time, so that ``render_seconds`` does not depend on whether a worker is warm."""
    import drjit as dr

    out = _Compiled()
    before = dr.flag(dr.JitFlag.KernelHistory)
    dr.kernel_history()  # drop what an earlier block left (reading the history clears it)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        yield out
    finally:
        history = dr.kernel_history()
        dr.set_flag(dr.JitFlag.KernelHistory, before)
        ms = sum(float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0))
                 for k in history)  # fmt: skip
        out.seconds = ms / 1000.0


def load_scene(
    params: RenderParams, bsdf: Any, mi: types.ModuleType, pass_spp: int
) -> tuple[Any, dict[str, Any], SceneSetup]:
    """The Mitsuba scene of ``params`` with ``bsdf`` on its object, loaded.

    ``pass_spp`` is the sampler's spp (the first pass's; each ``mi.render`` call overrides
    it). Returns ``(scene, scene dict, setup)``; raises :class:`JobFailed` naming the
    material or the scene when Mitsuba refuses them.
    """
    setup = SceneSetup(
        resolution=(params.resolution[0], params.resolution[1]),
        spp=pass_spp,
        max_depth=params.max_depth,
        lights=tuple(params.lights) if params.lights is not None else None,
        camera=params.camera,
    )
    try:
        scene_dict = build_scene(params.scene, mi, bsdf, setup)
    except ValueError as exc:  # e.g. a material with relief in a scene without a floor
        raise JobFailed(f"material: {exc}") from None
    # A model material with neural_max_depth needs the depth-aware path tracer (Sec. 5.3);
    # a fabric material needs each pixel's footprint (uv partials at pixel centres).
    try:
        scene_dict["integrator"] = integrator_for(mi, bsdf, scene_dict["integrator"])
    except ValueError as exc:
        raise JobFailed(f"material: {exc}") from None
    try:
        scene = mi.load_dict(scene_dict)
    except Exception as exc:  # Mitsuba reports scene errors as RuntimeError with C++ text
        raise JobFailed(f"scene {params.scene}: {mitsuba_message(exc)}") from None
    return scene, scene_dict, setup


def run_render(params: RenderParams, ctx: JobContext) -> None:
    """Render ``params`` and store ``image.exr``, ``preview.png`` and ``render.json``."""
    width, height = params.resolution
    ctx.progress(0.0, "starting Mitsuba")
    mi = load_mitsuba()
    variant = active_variant()
    bsdf = resolve_material(params.material, ctx, mi)
    passes = plan_passes(width, height, params.spp, PATHS_PER_PASS)
    seeds = [ctx.sub_seed(f"render/pass/{i}") for i in range(len(passes))]
    scene, scene_dict, setup = load_scene(params, bsdf, mi, passes[0])

    def report(i: int, done: int) -> None:
        ctx.progress(
            0.02 + 0.93 * done / params.spp, f"pass {i + 1}/{len(passes)}: {done}/{params.spp} spp"
        )

    with kernel_compile_timer() as compiled:
        started = time.perf_counter()
        image = render_passes(mi, scene, passes, seeds, on_pass=report)
        seconds = time.perf_counter() - started
    # The render's own cost (its result row): the passes without JIT compilation.
    ctx.measure("render_seconds", max(seconds - compiled.seconds, 0.0))
    bad = int(np.count_nonzero(~np.isfinite(image)))
    if bad:
        raise JobFailed(
            f"the render has {bad} non-finite pixel values (NaN or infinity); "
            f"the material returned invalid values"
        )

    ctx.put_bytes("image.exr", exr_bytes(image), "image/x-exr")
    ctx.put_bytes("preview.png", write_png(None, tonemap(image)), "image/png")
    ctx.put_json(
        "render.json",
        _metadata(
            params,
            setup,
            variant,
            mi.__version__,
            passes,
            seeds,
            image,
            integrator=str(scene_dict["integrator"]["type"]),
        ),
    )
    mpaths = width * height * params.spp / max(seconds, 1e-9) / 1e6
    log.info(
        "render %s: %dx%d, %d spp in %.3f s (%.2f Mpaths/s, %s)",
        ctx.job_id,
        width,
        height,
        params.spp,
        seconds,
        mpaths,
        variant,
    )
    default = params.material == DEFAULT_MATERIAL
    ctx.progress(
        1.0,
        f"rendered {width}x{height} at {params.spp} spp in {seconds:.2f} s "
        f"({mpaths:.1f} Mpaths/s, {variant})"
        + ("; no material given: the default grey diffuse (reflectance 0.5)" if default else ""),
    )


def _metadata(
    params: RenderParams,
    setup: SceneSetup,
    variant: str | None,
    version: str,
    passes: list[int],
    seeds: list[int],
    image: np.ndarray,
    *,
    integrator: str = "path",
) -> dict[str, Any]:
    scene = SCENES[params.scene]
    return {
        "scene": params.scene,
        "material": params.material,
        "resolution": list(params.resolution),
        "spp": params.spp,
        "max_depth": params.max_depth,
        "camera": scene.camera_for(setup).model_dump(mode="json"),
        "point_lights": [light.model_dump(mode="json") for light in scene.lights_for(setup)],
        "environment": "matforge studio_envmap"
        if params.scene in ("sphere_env", "cloth_plane")
        else None,
        "integrator": integrator,
        "sampler": "independent",
        "rfilter": "box",
        "passes": [{"spp": n, "seed": s} for n, s in zip(passes, seeds, strict=True)],
        "renderer": {"mitsuba": version, "variant": variant},
        "preview": {"curve": "aces", "exposure": 0.0, "encoding": "sRGB"},
        "image": {
            "width": int(image.shape[1]),
            "height": int(image.shape[0]),
            "mean_rgb": [float(v) for v in image.reshape(-1, 3).mean(axis=0)],
            "max": float(image.max()),
        },
    }


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``render.json``, one row (the scene) with size, samples and the
    image's mean RGB and maximum."""
    doc = read_typed(read("render.json"), RenderDocument)
    if doc is None:
        return None
    image = doc["image"]
    mean: list[float | None] = [*image["mean_rgb"], None, None, None]
    row = {
        "width": image["width"],
        "height": image["height"],
        "spp": doc["spp"],
        "mean_r": mean[0],
        "mean_g": mean[1],
        "mean_b": mean[2],
        "max": image["max"],
        "integrator": doc["integrator"],
        "variant": doc["renderer"]["variant"],
    }
    return ResultTable(
        title="Render", label_header="Scene", columns=list(row), rows={doc["scene"]: row}
    )


register(
    Kind(
        name="render",
        variant_bytes=True,
        params=RenderParams,
        runner=run_render,
        description="Path-traced reference image of a material in a built-in scene (Mitsuba 3, "
        "MATFORGE_VARIANT: LLVM or CUDA).",
        artifacts=("image.exr", "preview.png", "render.json"),
        documents={"render.json": RenderDocument},
        smoke={"resolution": [32, 32], "spp": 4, "max_depth": 4},
        figures=(
            Figure(
                "image.exr",
                caption=(
                    "The render (linear HDR, shown tone-mapped; preview.png is the same "
                    "picture in sRGB)."
                ),
                lead=True,
            ),
        ),
        summary=summarize,
        rows=render_rows,
        metrics=("render_seconds",),
    )
)
