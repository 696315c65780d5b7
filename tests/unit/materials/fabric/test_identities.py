"""Identities the aggregate of Eq. 3-5 must keep (Chen et al. 2024), on the watertight yarns.

- **Projected area** (Eq. 5): over whole tiles, the visible projected area of a height
  field is exactly ``cos theta`` for any direction (every ray from ``w`` meets the surface
  once), so ``A_P(wo) = cos theta_o`` and ``A_in(wi) = cos theta_i``; checked for every
  pattern, beta up to 2, theta 0-75 degrees, within Monte Carlo error (independent seeds).
- **Visibility** against brute-force ray casting: a ray from a surface point, stepped at a
  hundredth of a cell against the height field (bilinear on a raster of 64 texels per
  cell), independently of the march's adaptive steps and jitter.
- **Reciprocity** of ``f_P A_P`` for BRDF pairs with ``w = 1`` (the numerator of Eq. 3 is
  symmetric): the same sample points, swapped directions, equal to rounding.
- **Footprint consistency**: a footprint's numerator is the mean of its four half-size
  children's, and so its aggregate the A-weighted mean of theirs, within Monte Carlo error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from materials.fabric import yarn
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.array_ops import NumpyOps
from materials.fabric.integrand import visibility
from materials.fabric.params import FabricParams
from materials.fabric.patterns import PATTERNS
from tests.helpers.fabric_identities import area_over_cosine, direction, reciprocity_sides

OPS = NumpyOps()


@pytest.mark.parametrize("name", sorted(PATTERNS))
@pytest.mark.parametrize("beta", [0.7, 2.0])
def test01_projected_areas_are_cosines(name: str, beta: float) -> None:
    params = FabricParams(PATTERNS[name], beta=beta, u_max_deg=30.0, psi_deg=20.0)
    # J = 1 / n_z is heavy-tailed on the steep sides of long floats: enough samples that
    # the seeds' spread estimates the error.
    for attr, (mean, err) in area_over_cosine(params, samples=8192).items():
        # 4 standard errors, plus 1 % for the march's coarse steps at grazing angles
        # (integrand.py: -0.2 to -0.5 % on average against a 0.01-cell march).
        assert np.all(np.abs(mean - 1.0) <= 4 * err + 0.01), (attr, mean, err)


def _ray_cast(geo: yarn.YarnGeometry, s: float, t: float, h0: float, w: np.ndarray) -> bool:
    """Whether the ray from ``(s, t, h0)`` along ``w`` is blocked: 1/100-cell steps against
    the height field bilinear on a 64-texel-per-cell raster (computed here, per ray)."""
    tab = yarn.tables(OPS, geo)
    cell = min(geo.cell)
    step = cell / 100.0
    horizontal = math.hypot(w[0], w[1])
    if horizontal < 1e-9:
        return False
    travel = (geo.h_max - h0) * horizontal / w[2]
    k = np.arange(1, int(travel / step) + 2) * step  # horizontal distances
    x = s * geo.tile[0] + k * w[0] / horizontal
    y = t * geo.tile[1] + k * w[1] / horizontal
    rise = h0 + k * w[2] / horizontal
    res = cell / 64.0  # raster texel: bilinear between texel centres
    gx, gy = np.floor(x / res - 0.5), np.floor(y / res - 0.5)
    fx, fy = x / res - 0.5 - gx, y / res - 0.5 - gy
    hgt = np.zeros_like(x)
    for dy in (0, 1):
        for dx in (0, 1):
            cx, cy = (gx + dx + 0.5) * res, (gy + dy + 0.5) * res
            hv = yarn.height(OPS, geo, tab, cx / geo.tile[0], cy / geo.tile[1])
            hgt += (fx if dx else 1 - fx) * (fy if dy else 1 - fy) * hv
    return bool(np.any(hgt > rise + 2e-3))


@pytest.mark.parametrize("name", ["twill_3x3", "satin_5x5"])
def test02_visibility_against_ray_casting(name: str) -> None:
    params = FabricParams(PATTERNS[name], beta=1.0, u_max_deg=30.0)
    geo = yarn.YarnGeometry.from_params(params)
    tab = yarn.tables(OPS, geo)
    rng = np.random.default_rng(3)
    m = 400
    s, t = rng.uniform(0, 1, m), rng.uniform(0, 1, m)
    h0 = yarn.height(OPS, geo, tab, s, t)
    theta = np.radians(rng.uniform(30, 80, m))
    phi = rng.uniform(0, 2 * math.pi, m)
    w = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    v = visibility(
        OPS, geo, tab, s, t, h0, (w[0], w[1], w[2]), rng.uniform(0, 1, m), step=0.01,
        max_steps=1024,
    )  # fmt: skip
    ref = np.array([not _ray_cast(geo, s[i], t[i], h0[i], w[:, i]) for i in range(m)])
    agree = np.mean((v > 0.5) == ref)
    # Disagreements are rays grazing a crest within the two methods' tolerances (1e-3 and
    # 2e-3 of a cell in height, and the raster's bilinear smoothing): under 2 %.
    assert agree >= 0.98, (agree, ref.mean())
    assert 0.05 < ref.mean() < 0.95  # the test sees both outcomes


@pytest.mark.parametrize(
    ("name", "backend"),
    [("plain", "numpy"), ("twill_3x3", "numpy"), ("satin_5x5", "numpy"), ("twill_3x3", "drjit")],
)
def test03_reciprocity_of_the_numerator(name: str, backend: str) -> None:
    params = FabricParams(PATTERNS[name], beta=1.0, u_max_deg=30.0, w=1.0)
    lhs, rhs = reciprocity_sides(params, backend)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-9, atol=1e-12)


def test04_footprint_is_the_area_weighted_mean_of_its_children() -> None:
    params = FabricParams(PATTERNS["twill_3x3"], beta=1.0, u_max_deg=30.0)
    wi, wo = direction(40, 30), direction(35, 200)
    c, size = np.array([0.43, 0.58]), 0.6
    kids = [c + 0.25 * size * np.array([dx, dy]) for dx in (-1, 1) for dy in (-1, 1)]
    centres = np.array([c, *kids])
    sizes = np.array([size] + [size / 2] * 4)
    q = FootprintQueries(centres, sizes, np.tile(wi, (5, 1)), np.tile(wo, (5, 1)))
    runs = [estimate(params, q, samples=4096, seed=s, backend="drjit") for s in range(6)]
    num = np.stack([r.mean.sum(axis=1) * r.area for r in runs])  # numerators of Eq. 3
    diff = num[:, 0] - num[:, 1:].mean(axis=1)
    assert abs(diff.mean()) <= 4 * diff.std(ddof=1) / math.sqrt(len(runs)) + 1e-4
    agg = np.stack([r.mean.sum(axis=1) for r in runs])
    area = np.stack([r.area for r in runs])
    weighted = (agg[:, 1:] * area[:, 1:]).sum(axis=1) / area[:, 1:].sum(axis=1)
    d2 = agg[:, 0] - weighted
    assert abs(d2.mean()) <= 4 * d2.std(ddof=1) / math.sqrt(len(runs)) + 1e-4
