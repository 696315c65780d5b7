"""Reference renders against physics and against themselves.

Oracles:
- white furnace: a convex Lambertian object of albedo rho under a uniform environment of
  radiance L reflects exactly rho * L (it sees only the environment: rho/pi * integral of
  L cos over the hemisphere), and with paths of one segment it is black;
- a Lambertian plane under one point light of intensity I at height H reflects
  rho/pi * I * H / (H^2 + r^2)^(3/2) at distance r from the foot of the light
  (inverse-square law and Lambert's cosine law);
- the silhouette of the unit sphere computed from the camera's geometry (distance 4,
  35 degree field of view), independently of Mitsuba;
- invariance: background pixels do not depend on the sphere's material;
- determinism: same seed, same bytes; another seed, other bytes.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from evaluators.render.kind import RenderParams, plan_passes, run_render
from evaluators.render.scenes import (
    SCENES,
    SPHERE_CAMERA,
    Camera,
    PointLight,
    SceneSetup,
    build_scene,
    studio_envmap,
)
from jobapi.context import JobContext
from materials.backend import load_mitsuba
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import JobStore

DIFFUSE_HALF = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}


@pytest.fixture(scope="module")
def mitsuba_module() -> types.ModuleType:
    """Mitsuba with matforge's variant (LLVM, or the scalar fallback)."""
    return load_mitsuba()


@pytest.fixture
def evaluator_ctx(tmp_path: Path) -> Iterator[Callable[..., JobContext]]:
    """A factory of ``JobContext`` objects (``seed`` keyword) sharing one temporary store."""
    store = ArtifactStore(tmp_path / "store")
    jobs = JobStore(tmp_path / "jobs.sqlite")
    counter = iter(range(1, 1 << 30))

    def make(seed: int = 0) -> JobContext:
        work = tmp_path / f"work-{next(counter)}"
        work.mkdir()
        return JobContext(
            job_id=f"{next(counter):032x}",
            seed=seed,
            spec={},
            store=store,
            jobs=jobs,
            workdir=work,
        )

    yield make
    jobs.close()


def sphere_masks(n: int, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of an n x n image of the default sphere camera well inside / well outside the
    unit sphere's silhouette: its half-angle is asin(1/4) for a camera at distance 4."""
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(c, c)
    r = np.hypot(x, y)
    dist = float(np.linalg.norm(SPHERE_CAMERA.origin))
    edge = math.tan(math.asin(1.0 / dist)) / math.tan(math.radians(SPHERE_CAMERA.fov) / 2)
    return r < (1.0 - margin) * edge, r > (1.0 + margin) * edge


def furnace(mi, max_depth: int, radiance: list[float], spp: int = 64) -> np.ndarray:
    scene = build_scene(
        "sphere_points",
        mi,
        DIFFUSE_HALF,
        SceneSetup(resolution=(32, 32), spp=spp, max_depth=max_depth, lights=()),
    )
    scene["environment"] = {"type": "constant", "radiance": {"type": "rgb", "value": radiance}}
    return np.asarray(mi.render(mi.load_dict(scene), seed=11), dtype=np.float64)


def test01_white_furnace(mitsuba_module) -> None:
    radiance = np.array([1.0, 2.0, 0.5])
    img = furnace(mitsuba_module, 8, radiance.tolist())
    inside, outside = sphere_masks(32)
    assert inside.sum() > 300 and outside.sum() > 200
    ratio = img[inside] / (0.5 * radiance)
    # Mean over ~440 pixels at 64 spp: MC noise of the mean is ~0.1 %, per pixel ~3 %.
    np.testing.assert_allclose(ratio.mean(axis=0), 1.0, atol=0.01)
    assert float(np.abs(ratio - 1.0).max()) < 0.2
    np.testing.assert_allclose(
        img[outside], np.broadcast_to(radiance, img[outside].shape), rtol=1e-6
    )


def test02_one_segment_paths_see_only_emitters(mitsuba_module) -> None:
    img = furnace(mitsuba_module, 1, [1.0, 1.0, 1.0], spp=4)
    inside, outside = sphere_masks(32)
    assert float(np.abs(img[inside]).max()) == 0.0
    np.testing.assert_allclose(img[outside], 1.0, rtol=1e-6)


def test03_point_light_on_a_lambertian_plane(mitsuba_module) -> None:
    mi, n, cam_height, light_height, intensity, fov = mitsuba_module, 32, 3.0, 2.0, 4.0, 60.0
    camera = Camera(
        origin=(0.0, cam_height, 0.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, -1.0), fov=fov
    )
    light = PointLight(position=(0.0, light_height, 0.0), intensity=(intensity,) * 3)
    scene = build_scene(
        "plane_points", mi, DIFFUSE_HALF, SceneSetup((n, n), 16, 2, lights=(light,), camera=camera)
    )
    img = np.asarray(mi.render(mi.load_dict(scene), seed=1), dtype=np.float64)
    # The camera looks straight down, so the pixel centre at image coordinates (x, y) in
    # [-1, 1] sees the plane at distance r = h tan(fov / 2) |(x, y)| from the centre.
    c = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    x, y = np.meshgrid(c, c)
    r = cam_height * math.tan(math.radians(fov / 2)) * np.hypot(x, y)
    expected = 0.5 / math.pi * intensity * light_height / (light_height**2 + r**2) ** 1.5
    ratio = img / expected[..., None]
    assert abs(float(ratio.mean()) - 1.0) < 0.005  # pixel-footprint averaging only
    assert float(np.abs(ratio - 1.0).max()) < 0.03


def test04_materials_under_the_studio_envmap(mitsuba_module) -> None:
    mi = mitsuba_module
    renders = []
    for bsdf in (DIFFUSE_HALF, {"type": "roughconductor", "alpha": 0.2}):
        scene = build_scene("sphere_env", mi, bsdf, SceneSetup((24, 24), 8, 4))
        renders.append(np.asarray(mi.render(mi.load_dict(scene), seed=3)))
    inside, outside = sphere_masks(24)
    for img in renders:
        assert img.shape == (24, 24, 3) and np.isfinite(img).all() and img.min() >= 0.0
        assert img[inside].mean() > 0.01
    # The background is the environment, whatever the sphere is made of.
    np.testing.assert_array_equal(renders[0][outside], renders[1][outside])
    assert not np.array_equal(renders[0][inside], renders[1][inside])


def test05_studio_envmap_is_deterministic_and_bright_where_the_lights_are() -> None:
    env = studio_envmap(128, 64)
    assert env.shape == (64, 128, 3) and env.dtype == np.float32
    np.testing.assert_array_equal(env, studio_envmap(128, 64))
    assert env.min() > 0.0 and env.max() > 20.0  # sky and ground light, bright studio discs
    sky, ground = env[:28].mean(), env[36:].mean()
    assert sky > ground  # upper hemisphere (rows near the top) is the brighter sky


@pytest.mark.parametrize("scene", sorted(SCENES))
def test06_every_scene_renders(scene: str, evaluator_ctx) -> None:
    ctx = evaluator_ctx(seed=1)
    params = RenderParams.model_validate(
        {"scene": scene, "resolution": [16, 12], "spp": 2, "max_depth": 3}
    )
    run_render(params, ctx)
    assert set(ctx.artifacts) == {"image.exr", "preview.png", "render.json"}
    img = read_exr(ctx.store.path(ctx.artifacts["image.exr"].digest))
    assert img.shape == (12, 16, 3) and np.isfinite(img).all() and img.max() > 0.0


def test07_same_seed_same_bytes(evaluator_ctx) -> None:
    params = RenderParams.model_validate({"resolution": [24, 16], "spp": 6, "max_depth": 4})
    digests = []
    for seed in (5, 5, 6):
        ctx = evaluator_ctx(seed=seed)
        run_render(params, ctx)
        digests.append({name: rec.digest for name, rec in ctx.artifacts.items()})
    assert digests[0] == digests[1]
    assert digests[0]["image.exr"] != digests[2]["image.exr"]


def test08_passes_split_spp() -> None:
    for w, h, spp in [(8, 8, 1), (256, 256, 64), (512, 512, 1000), (4096, 4096, 3)]:
        passes = plan_passes(w, h, spp)
        assert sum(passes) == spp and len(set(passes)) <= 2 and min(passes) >= 1
        assert passes == sorted(passes, reverse=True)
    assert plan_passes(512, 512, 64) == [16, 16, 16, 16]  # 2^24 paths in passes of 2^22
    assert len(plan_passes(4096, 4096, 3)) == 3  # never below 1 spp per pass


class CancelAfter:
    """A monitor that records progress and reports cancellation after ``n`` reports."""

    def __init__(self, n: int) -> None:
        self.n, self.messages = n, []

    def report(self, progress: float, message: str | None) -> None:
        self.messages.append((progress, message))

    def cancelled(self) -> bool:
        return len(self.messages) > self.n


def test09_progress_per_pass_and_cancellation(evaluator_ctx, monkeypatch) -> None:
    import evaluators.render.kind as render_module
    from jobapi.errors import JobCancelled

    monkeypatch.setattr(render_module, "PATHS_PER_PASS", 16 * 16)  # 1 spp per pass
    params = RenderParams.model_validate({"resolution": [16, 16], "spp": 8, "max_depth": 2})
    ctx = evaluator_ctx(seed=3)
    ctx.monitor = CancelAfter(10**6)
    run_render(params, ctx)
    passes = [m for _, m in ctx.monitor.messages if m and m.startswith("pass ")]
    assert passes[0] == "pass 1/8: 1/8 spp" and passes[-1] == "pass 8/8: 8/8 spp"
    progress = [p for p, _ in ctx.monitor.messages]
    assert progress == sorted(progress) and progress[-1] == 1.0

    ctx = evaluator_ctx(seed=3)
    ctx.monitor = CancelAfter(3)
    with pytest.raises(JobCancelled):
        run_render(params, ctx)
    assert ctx.artifacts == {}
    assert len([m for _, m in ctx.monitor.messages if m and m.startswith("pass ")]) < 8


def test10_params_list_every_builtin_scene() -> None:
    from typing import get_args

    assert set(get_args(RenderParams.model_fields["scene"].annotation)) == set(SCENES)
