"""The BTF table BSDF (``btf_table``) and its interpolation between measured directions.

Oracles, each independent of the code under test:

- ``scipy.interpolate.LinearNDInterpolator`` (Qhull's Delaunay triangulation and its own
  barycentric point location) over the same projected directions, for the weights inside
  the hull; a brute-force closest point on the hull's boundary (dense sampling), for the
  weights outside it;
- the stored slice values themselves, at texel centres and measured directions (exact);
- the closed form of a Lambertian BTF, ``albedo / pi cos(theta_i)``, between and beyond
  the measured directions;
- Mitsuba's chi-square harness for ``sample`` against ``pdf``, and the closed forms of
  cosine sampling (pdf integral 1, weight = eval / pdf).
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.btf_table import (
    BTF_TABLE_NAME,
    BtfTable,
    build_table,
    put_table,
    register_btf_table_bsdf,
)
from materials.btf.angular import (
    build_direction_mesh,
    direction_weights,
    jit_direction_mesh,
    project,
)
from materials.btf.directions import SMALL_DIRECTIONS, preset_pairs, to_vector
from tests.helpers.mitsuba_probes import check_pdf_and_sampling, direction_chi2, hemisphere

SMALL = to_vector(*np.asarray(SMALL_DIRECTIONS).T)


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    register_btf_table_bsdf(mi)
    return mi


def weights(mi: types.ModuleType, dirs: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, ...]:
    """``(indices (M, 3), weights (M, 3))`` of the Dr.Jit interpolation at ``q``."""
    mesh = jit_direction_mesh(mi, build_direction_mesh(dirs))
    idx, w = direction_weights(mi, mesh, mi.Vector3f(*q.astype(np.float32).T))
    return np.stack([np.asarray(i) for i in idx], 1), np.stack([np.asarray(x) for x in w], 1)


def irregular(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return hemisphere(rng, n, max_deg=80.0).astype(np.float64)


SETS = {
    "small": SMALL,
    "ubo2014": preset_pairs("ubo2014")[0][::151],
    "irregular": irregular(1, 40),
}


@pytest.mark.parametrize("name", sorted(SETS))
def test01_weights_match_scipy_inside_the_hull(mi: types.ModuleType, name: str) -> None:
    """Inside the hull the interpolant is scipy's piecewise-linear one on the projected
    points, to 2e-5 of values in [0, 1]: float32 arithmetic, and weights below ``SNAP``
    (1e-5) dropped. Both triangulate the same
    (float32) directions with Qhull: rings make cocircular points, where the Delaunay
    triangulation, hence the interpolant, is ambiguous and depends on the input's bits."""
    from scipy.interpolate import LinearNDInterpolator

    dirs = SETS[name]
    rng = np.random.default_rng(2)
    q = hemisphere(rng, 20000)
    idx, w = weights(mi, dirs, q)
    assert np.all(w >= 0) and np.allclose(w.sum(axis=1), 1.0, atol=1e-6)
    values = rng.random(len(dirs))
    ours = (values[idx] * w).sum(axis=1)
    points = project(dirs.astype(np.float32))
    ref = LinearNDInterpolator(points, values)(project(q.astype(np.float64)))
    inside = np.isfinite(ref)
    print(f"\n{name}: {inside.mean():.0%} of the hemisphere inside the hull")
    assert inside.sum() > 1000
    np.testing.assert_allclose(ours[inside], ref[inside], atol=2e-5)


@pytest.mark.parametrize("name", sorted(SETS))
def test02_outside_the_hull_is_its_closest_boundary_point(mi: types.ModuleType, name: str) -> None:
    """Beyond the hull the value is scipy's interpolant at the closest point of the hull's
    boundary, found by brute force over 2000 points per hull edge (so within ~1e-3)."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import ConvexHull

    dirs = SETS[name]
    pts = project(dirs.astype(np.float32))
    rng = np.random.default_rng(3)
    q = hemisphere(rng, 3000)
    values = rng.random(len(dirs))
    interp = LinearNDInterpolator(pts, values)
    pq = project(q.astype(np.float64))
    outside = ~np.isfinite(interp(pq))
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    boundary = np.concatenate(
        [pts[a] + t * (pts[b] - pts[a]) for a, b in ConvexHull(pts).simplices]
    )
    nearest = boundary[np.argmin(((pq[outside, None, :] - boundary[None]) ** 2).sum(-1), axis=1)]
    ref = interp(nearest * (1.0 - 1e-9) + pts.mean(axis=0) * 1e-9)  # nudged inside
    idx, w = weights(mi, dirs, q[outside])
    ours = (values[idx] * w).sum(axis=1)
    assert outside.sum() > 100
    np.testing.assert_allclose(ours, ref, atol=2e-3)


def test03_degenerate_sets(mi: types.ModuleType) -> None:
    """One direction: weight 1 everywhere. Two: linear along the segment between their
    projections (the midpoint gets 0.5 each), held beyond its ends."""
    rng = np.random.default_rng(4)
    q = hemisphere(rng, 1000)
    idx, w = weights(mi, to_vector([20.0], [40.0]), q)
    assert np.all(idx == 0) and np.allclose(w.sum(axis=1), 1.0)
    two = to_vector([0.0, 60.0], [0.0, 0.0])
    mid = to_vector([30.0, 80.0, 10.0], [0.0, 180.0, 0.0])
    idx, w = weights(mi, two, mid)
    per = np.zeros((3, 2))
    for k in range(3):
        np.add.at(per[k], idx[k], w[k])
    np.testing.assert_allclose(per, [[0.5, 0.5], [1.0, 0.0], [5 / 6, 1 / 6]], atol=1e-5)


def slice_set(seed: int, h: int = 4, w: int = 8) -> tuple[np.ndarray, ...]:
    """The 36 pairs of the small set with random slices ``(36, h, w, 3)``."""
    wi, wo = preset_pairs("small")
    rgb = np.random.default_rng(seed).random((len(wi), h, w, 3)).astype(np.float32)
    return wi.astype(np.float32), wo.astype(np.float32), rgb


def table_bsdf(mi: types.ModuleType, table: BtfTable, **scale: float) -> Any:
    return mi.load_dict({"type": BTF_TABLE_NAME, "table": put_table(table), **scale})


def eval_at(
    mi: types.ModuleType, bsdf: Any, uv: np.ndarray, light: np.ndarray, view: np.ndarray
) -> np.ndarray:
    """``(N, 3)`` eval at uv ``(N, 2)``, light = Mitsuba's ``wo``, view = ``si.wi``, on a
    right-handed frame (``t = dp/dv``)."""
    import drjit as dr

    si = dr.zeros(mi.SurfaceInteraction3f, len(uv))
    si.uv = mi.Point2f(*uv.astype(np.float32).T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
    si.dp_dv = mi.Vector3f(0, 1, 0)
    si.wi = mi.Vector3f(*view.astype(np.float32).T)
    wo = mi.Vector3f(*light.astype(np.float32).T)
    return np.asarray(bsdf.eval(mi.BSDFContext(), si, wo), np.float64).T


def texel_centres(h: int, w: int) -> np.ndarray:
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    return np.stack([(ii.ravel() + 0.5) / w, (jj.ravel() + 0.5) / h], axis=1)


@pytest.mark.parametrize("drop", [0, 7])
def test04_exact_at_texel_centres_and_measured_directions(mi: types.ModuleType, drop: int) -> None:
    """At every texel centre (of a periodic repeat, too) and measured pair, eval returns
    the stored float32 value bit for bit, with every pair or with some missing (``drop``
    pairs removed: a list that is not a light x view product)."""
    wi, wo, rgb = slice_set(5)
    keep = np.sort(np.random.default_rng(6).permutation(len(wi))[drop:])
    wi, wo, rgb = wi[keep], wo[keep], rgb[keep]
    table = build_table(mi, wi, wo, rgb)
    assert table.complete == (drop == 0)
    bsdf = table_bsdf(mi, table, uv_scale_u=2.0, uv_scale_v=2.0)
    h, w = rgb.shape[1:3]
    uv = texel_centres(h, w) / 2.0 + np.array([0.5, 0.0])  # the second repeat in u
    for k in range(len(wi)):
        n = len(uv)
        out = eval_at(mi, bsdf, uv, np.tile(wi[k], (n, 1)), np.tile(wo[k], (n, 1)))
        assert np.array_equal(out.astype(np.float32), rgb[k].reshape(-1, 3)), k


def test05_lambertian_is_exact_everywhere(mi: types.ModuleType) -> None:
    """A Lambertian BTF (``albedo / pi cos(theta_i)``) measured at the 6 small directions is
    reproduced at random pairs over the whole hemisphere, as the closed form (the apparent
    BRDF is interpolated, the query's foreshortening applied)."""
    wi, wo, _ = slice_set(0)
    albedo = np.array([0.2, 0.5, 0.8])
    rgb = np.broadcast_to(
        (albedo / np.pi)[None, None, None, :] * wi[:, 2, None, None, None], (len(wi), 4, 8, 3)
    )
    bsdf = table_bsdf(mi, build_table(mi, wi, wo, rgb))
    rng = np.random.default_rng(7)
    light, view = hemisphere(rng, 5000), hemisphere(rng, 5000)
    uv = rng.random((5000, 2))
    out = eval_at(mi, bsdf, uv, light, view)
    ref = albedo[None, :] / np.pi * light[:, 2:3].astype(np.float64)
    np.testing.assert_allclose(out, ref, rtol=2e-5, atol=1e-7)
    # Below either horizon: 0.
    below = light * np.array([1, 1, -1], np.float32)
    assert np.all(eval_at(mi, bsdf, uv, below, view) == 0.0)
    assert np.all(eval_at(mi, bsdf, uv, light, view * np.array([1, 1, -1], np.float32)) == 0.0)


def test06_bilinear_and_periodic_in_space(mi: types.ModuleType) -> None:
    """Between texel centres the value is the bilinear blend of the four around it (the
    seam included: u = 0 sits between the last and the first column)."""
    wi, wo, rgb = slice_set(8)
    bsdf = table_bsdf(mi, build_table(mi, wi, wo, rgb))
    h, w = rgb.shape[1:3]
    uv = np.array([[0.0, 0.5 / h], [0.25 / w + 1.0, 1.0 / h], [3.0, 3.0]])
    light, view = np.tile(wi[9], (3, 1)), np.tile(wo[9], (3, 1))
    out = eval_at(mi, bsdf, uv, light, view)
    s = rgb[9].astype(np.float64)
    ref = [
        0.5 * (s[0, -1] + s[0, 0]),
        0.5 * (0.25 * s[0, -1] + 0.75 * s[0, 0]) + 0.5 * (0.25 * s[1, -1] + 0.75 * s[1, 0]),
        0.25 * (s[-1, -1] + s[-1, 0] + s[0, -1] + s[0, 0]),
    ]  # fmt: skip
    np.testing.assert_allclose(out, np.asarray(ref), rtol=1e-5)


def test07_left_handed_uv_mirrors_y(mi: types.ModuleType) -> None:
    """Where the shading frame's t is -dp/dv (Mitsuba's sphere), eval is that of the
    right-handed frame with the y components of both directions negated."""
    import drjit as dr

    wi, wo, rgb = slice_set(9)
    bsdf = table_bsdf(mi, build_table(mi, wi, wo, rgb))
    rng = np.random.default_rng(10)
    light, view, uv = hemisphere(rng, 500), hemisphere(rng, 500), rng.random((500, 2))
    si = dr.zeros(mi.SurfaceInteraction3f, 500)
    si.uv = mi.Point2f(*uv.astype(np.float32).T)
    si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1))
    si.dp_dv = mi.Vector3f(0, -2, 0)
    si.wi = mi.Vector3f(*view.T)
    left = np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*light.T)), np.float64).T
    flip = np.array([1, -1, 1], np.float32)
    right = eval_at(mi, bsdf, uv, light * flip, view * flip)
    np.testing.assert_allclose(left, right, rtol=1e-6, atol=1e-9)
    assert not np.allclose(left, eval_at(mi, bsdf, uv, light, view), rtol=1e-3)


def test08_sampling(mi: types.ModuleType) -> None:
    """Cosine sampling: Mitsuba's chi-square test of sample against pdf, pdf integral 1,
    weight = eval / pdf, eval_pdf = (eval, pdf)."""
    wi, wo, rgb = slice_set(11)
    table = build_table(mi, wi, wo, rgb)
    bsdf = table_bsdf(mi, table)
    rng = np.random.default_rng(12)
    for deg in (0.0, 50.0):
        integral, _, _ = check_pdf_and_sampling(mi, bsdf, deg, 1 << 16, rng)
        assert abs(integral - 1.0) < 0.02
    t = math.radians(40.0)
    plugin = {"type": BTF_TABLE_NAME, "table": put_table(table)}
    ok, p, messages = direction_chi2(mi, plugin, (math.sin(t), 0.0, math.cos(t)))
    print(f"\nchi2 at 40 deg: p = {p:.3f}")
    assert ok, messages


def test09_refusals(mi: types.ModuleType) -> None:
    wi, wo, rgb = slice_set(0)
    with pytest.raises(ValueError, match="wi, wo"):
        build_table(mi, wi[:3], wo, rgb)
    with pytest.raises(RuntimeError, match="no table registered"):
        mi.load_dict({"type": BTF_TABLE_NAME, "table": "nothing"})
    with pytest.raises(RuntimeError, match="uv_scale must be positive"):
        table = build_table(mi, wi, wo, rgb)
        mi.load_dict({"type": BTF_TABLE_NAME, "table": put_table(table), "uv_scale_u": 0.0})
    with pytest.raises(ValueError, match="distinct"):
        build_direction_mesh(np.concatenate([SMALL, SMALL[:1]]))
    with pytest.raises(ValueError, match="above the plane"):
        build_direction_mesh(SMALL * np.array([1, 1, -1]))
