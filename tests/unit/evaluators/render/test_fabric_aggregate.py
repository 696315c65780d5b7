"""The ``fabric_aggregate`` BSDF: each ``eval`` is an unbiased one-sample estimate of Eq. 3-8.

Oracles:

- ``materials.fabric.aggregate.estimate`` (numpy backend, many independent samples, its own
  standard error) at the same footprint: the mean of many ``eval`` calls must match it
  within Monte Carlo error (reflection, transmission, small and large footprints, both
  fabric sides, and the one-tile fallback footprint);
- closed forms for the sampling density (cosine-weighted, ``P_REFLECT`` on the viewer's
  side, integrating to 1) and for the slope bound (every rasterised normal lies below it);
- Mitsuba's chi-square harness (:mod:`mitsuba.chi2`) for the directions ``sample`` draws
  against ``pdf``, both sides, footprint and fallback.
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from evaluators.render.bsdfs.fabric_aggregate import fabric_bsdf
from evaluators.render.bsdfs.fabric_footprint import P_REFLECT
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.params import FabricParams, params_json
from materials.fabric.yarn import max_slope, rasterize
from tests.helpers.mitsuba_probes import direction_chi2

N_EVAL = 1 << 17
Z_MAX = 4.5

PARAMS = FabricParams(
    "twill_3x3",
    psi_deg=(20.0, -10.0),
    u_max_deg=25.0,
    alpha=(0.3, 0.5),
    beta=0.8,
    kd_warp=(0.8, 0.3, 0.2),
    kd_weft=(0.2, 0.4, 0.7),
    ks_warp=0.5,
    ks_weft=(0.9, 0.8, 0.3),
)


def unit(*v: float) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=np.float64)
    a /= np.linalg.norm(a)
    return float(a[0]), float(a[1]), float(a[2])


def mean_eval(
    mi: types.ModuleType,
    bsdf: object,
    view: tuple[float, float, float],
    light: tuple[float, float, float],
    centre: tuple[float, float],
    partials: tuple[tuple[float, float], tuple[float, float]],
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error of ``N_EVAL`` evals at one footprint (``tiles_per_uv`` 1)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, N_EVAL)
    si.wi = mi.Vector3f(*view)
    si.uv = mi.Point2f(*centre)
    si.duv_dx = mi.Vector2f(*partials[0])
    si.duv_dy = mi.Vector2f(*partials[1])
    si.time = dr.arange(mi.Float, N_EVAL) / N_EVAL  # what fabric_path stores: fresh seeds
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    values = np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*light)).numpy()).T
    return values.mean(axis=0), values.std(axis=0) / math.sqrt(N_EVAL)


def reference(
    view: tuple[float, float, float],
    light: tuple[float, float, float],
    centre: tuple[float, float],
    size: float,
    params: FabricParams = PARAMS,
) -> tuple[np.ndarray, np.ndarray]:
    queries = FootprintQueries(
        np.array([centre]), np.array([size]), np.array([light]), np.array([view])
    )
    est = estimate(params, queries, samples=1 << 15, sampler="independent", replicates=2)
    return est.recombine(params)[0], est.stderr[0] @ params.albedos()


CASES = {
    "reflection_small": (unit(0.3, 0.2, 0.9), unit(-0.5, 0.1, 0.8), (0.3, 0.6), 0.4),
    "transmission": (unit(0.6, -0.3, 0.7), unit(0.2, 0.5, -0.8), (0.1, 0.2), 1.0),
    "grazing_tiny": (unit(0.8, 0.1, 0.35), unit(-0.7, 0.0, 0.7), (0.7, 0.9), 0.15),
}


@pytest.mark.parametrize("case", list(CASES))
def test01_eval_matches_aggregate(mi: types.ModuleType, case: str) -> None:
    view, light, centre, size = CASES[case]
    bsdf = fabric_bsdf(mi, PARAMS, tiles_per_uv=1.0)
    mean, se = mean_eval(mi, bsdf, view, light, centre, ((size, 0.0), (0.0, size)))
    ref, ref_se = reference(view, light, centre, size)
    z = (mean - ref) / np.sqrt(se**2 + ref_se**2)
    assert np.all(ref > 0.0)
    assert np.all(np.abs(z) < Z_MAX), (mean, ref, z)


@pytest.mark.parametrize("case", list(CASES))
def test01b_eval_matches_aggregate_with_jins_yarn_profile(mi: types.ModuleType, case: str) -> None:
    """As test01 for ``yarn_profile: jin`` (steeper closing band: a larger rejection bound)."""
    params = PARAMS.replace(yarn_profile="jin")
    view, light, centre, size = CASES[case]
    bsdf = fabric_bsdf(mi, params, tiles_per_uv=1.0)
    mean, se = mean_eval(mi, bsdf, view, light, centre, ((size, 0.0), (0.0, size)))
    ref, ref_se = reference(view, light, centre, size, params)
    z = (mean - ref) / np.sqrt(se**2 + ref_se**2)
    assert np.all(ref > 0.0)
    assert np.all(np.abs(z) < Z_MAX), (mean, ref, z)


def test02_back_side_is_mirrored(mi: types.ModuleType) -> None:
    """Seen from below, the sheet answers as the front does for mirrored directions."""
    view, light, centre, size = CASES["reflection_small"]
    bsdf = fabric_bsdf(mi, PARAMS, tiles_per_uv=1.0)
    partials = ((size, 0.0), (0.0, size))
    front, se_f = mean_eval(mi, bsdf, view, light, centre, partials)
    flip = (view[0], view[1], -view[2]), (light[0], light[1], -light[2])
    back, se_b = mean_eval(mi, bsdf, *flip, centre, partials)
    assert np.all(np.abs(front - back) < Z_MAX * np.hypot(se_f, se_b))


def test03_fallback_footprint_is_one_tile(mi: types.ModuleType) -> None:
    """Without uv partials the footprint is one tile: the tile average, at any centre."""
    view, light = unit(0.4, -0.2, 0.9), unit(-0.3, 0.3, 0.9)
    bsdf = fabric_bsdf(mi, PARAMS, tiles_per_uv=3.0)
    ref, ref_se = reference(view, light, (0.5, 0.5), 1.0)
    for centre in ((0.0, 0.0), (0.37, 0.81)):
        mean, se = mean_eval(mi, bsdf, view, light, centre, ((0.0, 0.0), (0.0, 0.0)))
        assert np.all(np.abs(mean - ref) < Z_MAX * np.sqrt(se**2 + ref_se**2)), (mean, ref)


def test04_sampling_density(mi: types.ModuleType) -> None:
    import drjit as dr

    n = 1 << 16
    bsdf = fabric_bsdf(mi, PARAMS, tiles_per_uv=1.0)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*unit(0.3, 0.1, 0.9))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    rng = np.random.default_rng(5)
    s1 = mi.Float(rng.random(n, dtype=np.float32))
    s2 = mi.Point2f(rng.random((2, n), dtype=np.float32))
    ctx = mi.BSDFContext()
    bs, weight = bsdf.sample(ctx, si, s1, s2)
    wo = np.asarray(bs.wo.numpy()).T
    pdf = np.asarray(bs.pdf.numpy())
    side = np.where(wo[:, 2] > 0, P_REFLECT, 1.0 - P_REFLECT)
    np.testing.assert_allclose(pdf, side * np.abs(wo[:, 2]) / math.pi, rtol=1e-5, atol=1e-7)
    # The same float32 formula at the same wo (bitwise equal here); 1e-6 leaves 8 ulps.
    np.testing.assert_allclose(np.asarray(bsdf.pdf(ctx, si, bs.wo).numpy()), pdf, rtol=1e-6)
    assert abs(np.mean(wo[:, 2] > 0) - P_REFLECT) < 0.01
    assert np.all(np.isfinite(np.asarray(weight.numpy())))
    # The density integrates to 1 over the sphere (uniform-sphere Monte Carlo).
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    dens = np.asarray(bsdf.pdf(ctx, si, mi.Vector3f(u.T.astype(np.float32))).numpy())
    assert abs(dens.mean() * 4.0 * math.pi - 1.0) < 0.02


@pytest.mark.parametrize("pattern", ["plain", "satin_5x10"])
def test05_slope_bound(pattern: str) -> None:
    """``max_slope`` bounds every ply normal's tangent (the rejection sampler needs it)."""
    params = PARAMS.replace(pattern=pattern, beta=(1.5, 0.7), u_max_deg=(40.0, 15.0))
    normal = rasterize(params, 256).normal.reshape(-1, 3)
    tan = np.hypot(normal[:, 0], normal[:, 1]) / normal[:, 2]
    bound = max_slope(params)
    assert tan.max() <= bound * (1 + 1e-4)
    assert tan.max() >= 0.6 * bound  # the bound is attained at the edges, not loose


#: (incidence in degrees, view side, footprint partials in uv) of the chi-square cases. The
#: sampler does not depend on the view's azimuth or angle, only on its side of the sheet.
CHI2_CASES = [
    (30.0, 1.0, ((0.01, 0.002), (-0.001, 0.01))),
    (60.0, -1.0, ((0.0, 0.0), (0.0, 0.0))),
]


@pytest.mark.parametrize(
    ("deg", "side", "duv"), CHI2_CASES, ids=[f"{d:g}deg-side{s:+g}" for d, s, _ in CHI2_CASES]
)
def test06_chi2_sampling(
    mi: types.ModuleType, deg: float, side: float, duv: tuple[tuple[float, float], ...]
) -> None:
    """``sample``'s directions follow ``pdf`` (Mitsuba's chi-square harness, 1 M draws):
    reflection and transmission lobes, the viewer on either side of the sheet."""
    t = math.radians(deg)
    wi = (math.sin(t), 0.0, side * math.cos(t))
    plugin = {"type": "fabric_aggregate", "params": params_json(PARAMS), "tiles_per_uv": 8.0}
    fabric_bsdf(mi, PARAMS)  # registers the plugin for this variant
    ok, p, messages = direction_chi2(mi, plugin, wi, duv=duv, test_count=len(CHI2_CASES))
    print(f"\nchi2 fabric_aggregate at {deg:g} deg, side {side:+g}: p = {p:.3f}")
    assert ok, messages
