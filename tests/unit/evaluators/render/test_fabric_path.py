"""Renders with the ``fabric_aggregate`` BSDF and the ``fabric_path`` integrator.

Oracles:

- **Huge footprints** (analytic limit): an orthographic view of a plane under a
  directional light, with so many tiles per uv that each pixel covers about 16 x 32 tiles.
  Every pixel then converges to ``E f_P`` of the tile-averaged aggregate, whatever the uv
  offset, which ``aggregate.estimate`` (numpy) computes for a one-tile footprint at any
  centre. Two tile densities (aligned and not) must both agree.
- **White furnace**: a two-sided plane under a constant unit environment; a pixel is the
  directional albedo ``int f_P(wi, wo) dwi`` over both sides, checked against the numpy
  estimator integrated over the sphere. Closed form for flat yarns (``beta = 0``) with unit
  ``k_d`` and no ``k_s``: the yarns' area fraction, ``1 - gap`` (Lambertian, gaps are
  black). (Unit ``k_d`` and ``k_s`` together may exceed 1: Eq. 8 adds them; measured 1.04
  for flat yarns.)
- **1 spp vs 256 spp**: the 1-spp image is an unbiased, noisier version of the 256-spp one:
  the image means agree by a z-test on the per-pixel differences, and the 1-spp per-pixel
  variance is about 256 times that of the 256-spp image (measured between two seeds).
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.fabric_aggregate import fabric_bsdf
from evaluators.render.integrators import integrator_for
from evaluators.render.integrators.fabric_path import register_fabric_integrator
from evaluators.render.scenes import SceneSetup, build_scene
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.params import FabricParams

THETA_VIEW = math.radians(60.0)
LIGHT = np.array([0.5, 0.7, -0.3]) / np.linalg.norm([0.5, 0.7, -0.3])  # towards the light
PARAMS = FabricParams(
    "twill_3x3",
    psi_deg=20.0,
    u_max_deg=25.0,
    alpha=0.4,
    beta=0.8,
    kd_warp=(0.8, 0.3, 0.2),
    kd_weft=(0.2, 0.4, 0.7),
    ks_warp=0.5,
    ks_weft=(0.9, 0.8, 0.3),
)


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    register_fabric_integrator(mi)
    return mi


def plane_scene(mi: types.ModuleType, bsdf: Any, emitter: dict[str, Any], res: int) -> Any:
    """A 4x4 plane (normal +y, uv along world x and -z) seen orthographically at 60 degrees
    from its normal; the view covers 1 x 2 world units, i.e. 1/4 x 1/2 of the uv range."""
    eye = [0.0, 3.0 * math.sin(THETA_VIEW), 3.0 * math.cos(THETA_VIEW)]
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "fabric_path", "max_depth": 3},
            "sensor": {
                "type": "orthographic",
                "to_world": mi.ScalarTransform4f()
                .look_at(origin=eye, target=[0, 0, 0], up=[0, 1, 0])
                .scale([0.5, 0.5, 1.0]),
                "film": {
                    "type": "hdrfilm",
                    "width": res,
                    "height": res,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": 1},
            },
            "plane": {
                "type": "rectangle",
                "bsdf": bsdf,
                "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale([2, 2, 1]),
            },
            "emitter": emitter,
        }
    )


def render(mi: types.ModuleType, scene: Any, spp: int, seed: int) -> np.ndarray:
    return np.asarray(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)[..., :3]


def test01_huge_footprint_is_the_tile_average(mi: types.ModuleType) -> None:
    # World direction (x, y, z) is (x, -z, y) in the plane's shading frame (s = +x, n = +y).
    wi = np.array([[LIGHT[0], -LIGHT[2], LIGHT[1]]])
    wo = np.array([[0.0, -math.cos(THETA_VIEW), math.sin(THETA_VIEW)]])
    queries = FootprintQueries(np.array([[0.3, 0.7]]), np.array([1.0]), wi, wo)
    est = estimate(PARAMS, queries, samples=1 << 15, sampler="sobol", replicates=8)
    ref, ref_se = est.recombine(PARAMS)[0], est.stderr[0] @ PARAMS.albedos()
    light = {"type": "directional", "direction": (-LIGHT).tolist(), "irradiance": 1.0}
    for tiles in (512.0, 517.3):  # 8 px: 16 x 32 tiles per pixel, aligned and not
        scene = plane_scene(mi, fabric_bsdf(mi, PARAMS, tiles_per_uv=tiles), light, res=8)
        px = render(mi, scene, spp=512, seed=1).reshape(-1, 3)
        mean, se = px.mean(axis=0), px.std(axis=0, ddof=1) / math.sqrt(len(px))
        z = (mean - ref) / np.sqrt(se**2 + ref_se**2)
        assert np.all(np.abs(z) < 4.5), (tiles, mean, ref, z)
        assert np.all(np.abs(mean / ref - 1.0) < 0.02)


def furnace_reference(params: FabricParams, wo: np.ndarray, n: int = 400) -> tuple[float, float]:
    """``int f_P(wi, wo) dwi`` over the sphere (both sides), red channel, for a footprint
    of two tiles (the pixels here cover 2 x 4 tiles): cosine-weighted Fibonacci directions
    on each hemisphere (``f_P`` includes ``|cos theta_i|``, so ``f_P / pdf`` is smooth), the
    numpy estimator at 512 Sobol samples each; returns the value and a standard error."""
    k = np.arange(n // 2) + 0.5
    r = np.sqrt(k / (n // 2))  # cosine-weighted: the disk's area element
    phi = math.pi * (1.0 + math.sqrt(5.0)) * k
    up = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)], axis=1)
    wi = np.concatenate([up, up * np.array([1.0, 1.0, -1.0])])
    centres = np.random.default_rng(4).uniform(0.0, 1.0, (len(wi), 2))
    q = FootprintQueries(centres, np.full(len(wi), 2.0), wi, np.tile(wo, (len(wi), 1)))
    est = estimate(params, q, samples=512, seed=3, backend="drjit")
    # pdf = |cos| / pi on each hemisphere; each hemisphere is half the points.
    values = est.recombine(params)[:, 0] * math.pi / np.abs(wi[:, 2])
    halves = values.reshape(2, -1).mean(axis=1)
    errs = values.reshape(2, -1).std(axis=1, ddof=1) / math.sqrt(n // 2)
    return float(halves.sum()), float(np.hypot(*errs))


@pytest.mark.parametrize(("beta", "kd", "ks"), [(0.0, 1.0, 0.0), (1.0, 1.0, 0.0), (2.0, 0.0, 1.0)])
def test02_white_furnace(mi: types.ModuleType, beta: float, kd: float, ks: float) -> None:
    """A constant unit environment: each pixel is ``int f_P(wi, wo) dwi``. Against the
    numpy estimator integrated over the sphere (an independent path: no renderer, no
    rejection sampling); flat Lambertian yarns also against the closed form ``1 - gap``."""
    params = FabricParams(
        "satin_5x5", alpha=0.5, beta=beta, u_max_deg=30.0,
        kd_warp=kd, kd_weft=kd, ks_warp=ks, ks_weft=ks,
    )  # fmt: skip
    constant = {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}
    scene = plane_scene(mi, fabric_bsdf(mi, params, tiles_per_uv=64.0), constant, res=8)
    px = render(mi, scene, spp=256, seed=2)[..., 0].ravel()
    mean, se = px.mean(), px.std(ddof=1) / math.sqrt(px.size)
    wo = np.array([0.0, -math.cos(THETA_VIEW), math.sin(THETA_VIEW)])  # the eye, local
    ref, ref_se = furnace_reference(params, wo)
    # 4.5 combined standard errors, plus 1 %: the BSDF's rejection sampler (-0.2 % at its
    # 1024 tries) and the pixels' 2 x 4-tile footprints against the reference's 2 x 2.
    print(f"\nfurnace beta {beta}: render {mean:.4f} +- {se:.4f}, numpy {ref:.4f} +- {ref_se:.4f}")
    assert abs(mean - ref) <= 4.5 * math.hypot(se, ref_se) + 0.01 * ref, (mean, se, ref, ref_se)
    if beta == 0.0:
        assert mean == pytest.approx(0.8, abs=4.5 * se + 1e-3)  # closed form: 1 - gap
    assert 0.05 < mean <= 1.0 + 4.5 * se


def test03_one_spp_is_unbiased_and_noisier(mi: types.ModuleType) -> None:
    params = PARAMS.replace(pattern="plain")
    bsdf = fabric_bsdf(mi, params, tiles_per_uv=8.0)
    setup = SceneSetup(resolution=(24, 24), spp=1, max_depth=2)
    scene_dict = build_scene("plane_points", mi, bsdf, setup)
    scene_dict["integrator"] = integrator_for(mi, bsdf, scene_dict["integrator"])
    assert scene_dict["integrator"]["type"] == "fabric_path"
    scene = mi.load_dict(scene_dict)
    ref = render(mi, scene, spp=256, seed=1)
    ref2 = render(mi, scene, spp=256, seed=2)
    one = render(mi, scene, spp=1, seed=3)
    d = (one - ref).reshape(-1, 3)
    z = d.mean(axis=0) / (d.std(axis=0, ddof=1) / math.sqrt(len(d)))
    assert np.all(np.abs(z) < 4.0), z
    var_one = d.var(axis=0)
    var_256 = ((ref2 - ref) ** 2).reshape(-1, 3).mean(axis=0) / 2.0
    ratio = var_one / var_256
    assert np.all((ratio > 100.0) & (ratio < 600.0)), ratio


def test04_integrator_matches_path_on_other_materials(mi: types.ModuleType) -> None:
    """``fabric_path`` is Mitsuba's ``path`` estimator apart from the pixel-centre rays: on a
    rough conductor under point lights and the environment, away from silhouettes, the two
    agree within noise (Mitsuba's own integrator is the oracle)."""
    bsdf = {"type": "roughconductor", "alpha": 0.3, "material": "Cu"}
    setup = SceneSetup(resolution=(24, 24), spp=64, max_depth=4)
    images = {}
    for integrator in ("path", "fabric_path"):
        scene_dict = build_scene("cloth_plane", mi, bsdf, setup)
        scene_dict["integrator"] = {"type": integrator, "max_depth": 4}
        images[integrator] = render(mi, mi.load_dict(scene_dict), spp=256, seed=4)
    a, b = (images[k][14:].reshape(-1, 3) for k in ("path", "fabric_path"))  # cloth rows
    d = a - b  # per pixel: the scene's spatial variation cancels
    z = d.mean(axis=0) / (d.std(axis=0, ddof=1) / math.sqrt(len(d)))
    assert np.all(np.abs(z) < 4.5), z
    assert a.mean() > 0.02
