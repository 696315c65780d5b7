"""Yarn geometry (Jin et al. 2022): n_p, t_p, height and yarn id over a tile.

Oracles: orthonormality; coverage fractions counted from the pattern matrix and the 0.2 gap;
the plain weave's symmetry under exchanging warp and weft (a reflection about the diagonal
plus a one-cell shift, which also flips the twist's handedness); beta = 0 is flat; the
height field's finite-difference slopes against the normals' slopes where the model says
they agree; the -ln cos polynomial against numpy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from materials.fabric import yarn
from materials.fabric.array_ops import NumpyOps
from materials.fabric.params import FabricParams, sample_params
from materials.fabric.patterns import PATTERNS
from materials.fabric.yarn import max_slope

OPS = NumpyOps()


@pytest.mark.parametrize("name", sorted(PATTERNS))
def test01_frames_are_orthonormal(name: str) -> None:
    params = sample_params(np.random.default_rng(len(name)), name)
    maps = yarn.rasterize(params, 96)
    n, t = maps.normal.astype(np.float64), maps.tangent.astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(t, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.sum(n * t, axis=-1), 0.0, atol=1e-5)
    # Slopes stay within max_slope's bound (the rejection sampler of fabric_aggregate needs it).
    slope = np.hypot(n[..., 0], n[..., 1]) / n[..., 2]
    assert slope.max() <= yarn.max_slope(params) * (1 + 1e-4)
    geo = yarn.YarnGeometry.from_params(params)
    assert np.all(maps.height >= 0) and maps.height.max() <= geo.h_max + 1e-6
    assert np.all(maps.height[maps.yarn == yarn.GAP] == 0)


@pytest.mark.parametrize("name", ["plain", "twill_3x3", "satin_5x5", "satin_5x10"])
def test02_coverage_fractions(name: str) -> None:
    pat = PATTERNS[name]
    # 40 pixels per cell: the gap strips (4 pixels each side) fall on pixel boundaries.
    maps = yarn.rasterize(FabricParams(pat), 40 * pat.shape[1])
    frac = np.bincount(maps.yarn.ravel(), minlength=3) / maps.yarn.size
    # Counted by hand: yarns are 80 % of their cell's width, the rest is gap.
    expected_warp = 0.8 * pat.warp_up.sum() / pat.warp_up.size
    expected_weft = 0.8 * (~pat.warp_up).sum() / pat.warp_up.size
    np.testing.assert_allclose(frac, [0.2, expected_warp, expected_weft], atol=4e-3)


@pytest.mark.parametrize("psi", [0.0, 25.0])
def test03_plain_weave_is_symmetric_under_warp_weft_exchange(psi: float) -> None:
    """(s, t) -> (t + 1/2, s) swaps warp and weft; x/y components of n_p, t_p swap too.

    The reflection flips handedness, so a warp twist psi maps to a weft twist -psi.
    """
    params = FabricParams(
        PATTERNS["plain"], psi_deg=(psi, -psi), u_max_deg=(30, 30), beta=(0.7, 0.7)
    )
    res = 64
    m = yarn.rasterize(params, res)
    r, c = np.meshgrid(np.arange(res), np.arange(res), indexing="ij")
    r2, c2 = c, (r + res // 2) % res  # pixel of the mapped point (t + 1/2, s)
    swap_id = np.array([yarn.GAP, yarn.WEFT, yarn.WARP], dtype=np.uint8)
    np.testing.assert_array_equal(m.yarn[r2, c2], swap_id[m.yarn])
    np.testing.assert_allclose(m.height[r2, c2], m.height, atol=1e-6)
    np.testing.assert_allclose(m.normal[r2, c2], m.normal[..., [1, 0, 2]], atol=1e-6)
    on_yarn = m.yarn != yarn.GAP  # a gap's tangent is an arbitrary placeholder
    np.testing.assert_allclose(
        m.tangent[r2, c2][on_yarn], m.tangent[..., [1, 0, 2]][on_yarn], atol=1e-6
    )


def test04_beta_zero_is_flat() -> None:
    params = FabricParams(PATTERNS["twill_5x5"], psi_deg=(30, -20), beta=(0.0, 0.0))
    m = yarn.rasterize(params, 64)
    np.testing.assert_allclose(m.normal, np.broadcast_to([0, 0, 1], m.normal.shape), atol=1e-7)
    assert np.all(m.height == 0) and np.all(np.abs(m.tangent[..., 2]) < 1e-7)
    assert yarn.YarnGeometry.from_params(params).h_max == 0.0
    # psi = 0: the fibres run along the yarn axis (warp along y, weft along x).
    flat = yarn.rasterize(params.replace(psi_deg=(0.0, 0.0)), 64)
    for kind, axis in ((yarn.WARP, [0.0, 1.0, 0.0]), (yarn.WEFT, [1.0, 0.0, 0.0])):
        got = flat.tangent[flat.yarn == kind]
        np.testing.assert_allclose(got, np.broadcast_to(axis, got.shape), atol=1e-6)


def surface_at(params: FabricParams, s: np.ndarray, t: np.ndarray) -> yarn.Surface:
    geo = yarn.YarnGeometry.from_params(params)
    return yarn.surface(OPS, geo, yarn.tables(OPS, geo), s, t)


def test05_normals_are_the_height_gradient() -> None:
    """n_p is the normal of the height field, everywhere on the yarns: central differences
    of ``height`` against ``-n_xy / n_z`` at random points (the height uses the -ln cos
    polynomial, good to 2e-5, so slopes agree to about 1e-3 relative where they are steep)."""
    params = FabricParams(PATTERNS["satin_5x5"], u_max_deg=(35, 35), beta=(0.8, 0.8))
    pat = params.pattern
    rng = np.random.default_rng(0)
    s, t = rng.uniform(0, 1, 4000), rng.uniform(0, 1, 4000)
    surf = surface_at(params, s, t)
    eps = 1e-5
    tw, th = pat.tile_size
    dx = (surface_at(params, s + eps, t).height - surface_at(params, s - eps, t).height) / (
        2 * eps * tw
    )
    dy = (surface_at(params, s, t + eps).height - surface_at(params, s, t - eps).height) / (
        2 * eps * th
    )
    on = surf.warp | surf.weft
    gx, gy = -surf.normal[0] / surf.normal[2], -surf.normal[1] / surf.normal[2]
    np.testing.assert_allclose(dx[on], gx[on], rtol=2e-3, atol=1e-3)
    np.testing.assert_allclose(dy[on], gy[on], rtol=2e-3, atol=1e-3)


def test05b_watertight() -> None:
    """The height field is continuous across every cell edge (float ends, yarn edges, gap
    strips): no walls, for every pattern at the largest beta and inclination. A step of
    2e-7 tile units crosses each edge; the largest slope (max_slope) bounds the change."""
    for name in sorted(PATTERNS):
        params = FabricParams(PATTERNS[name], u_max_deg=(75, 75), beta=(2.0, 2.0))
        rows, cols = params.pattern.shape
        bound = 2e-7 * max(params.pattern.tile_size) * max_slope(params) + 1e-5
        u = (np.arange(500) + 0.5) / 500
        s_edges = np.repeat(np.arange(cols) / cols, len(u))
        t_edges = np.repeat(np.arange(rows) / rows, len(u))
        for s, t, ds, dt in (
            (s_edges, np.tile(u, cols), 1e-7, 0.0),
            (np.tile(u, rows), t_edges, 0.0, 1e-7),
        ):
            jump = (
                surface_at(params, s + ds, t + dt).height
                - surface_at(params, s - ds, t - dt).height
            )
            assert np.abs(jump).max() < bound, (name, float(np.abs(jump).max()))


def test06_neg_log_cos_polynomial() -> None:
    x = np.linspace(-yarn.ROLL_MAX, yarn.ROLL_MAX, 10001)
    approx = yarn.neg_log_cos(OPS, x.astype(np.float32)).astype(np.float64)
    assert np.max(np.abs(approx + np.log(np.cos(x)))) < 3e-5


def test07_h_max_is_attained_at_a_crest() -> None:
    params = FabricParams(PATTERNS["twill_3x3"], u_max_deg=(20, 40), beta=(0.5, 1.0))
    geo = yarn.YarnGeometry.from_params(params)
    m = yarn.rasterize(params, 600)
    assert m.height.max() == pytest.approx(geo.h_max, rel=2e-3)
    # The weft (u_max 40 deg, beta 1) is the taller yarn here.
    assert m.height[m.yarn == yarn.WEFT].max() > m.height[m.yarn == yarn.WARP].max()
    assert math.isfinite(geo.h_max)
