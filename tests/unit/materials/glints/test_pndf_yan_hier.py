"""Yan et al. 2016's hierarchical P-NDF (:mod:`materials.glints.pndf_yan_hier`) against the
brute force over the same lobes (:func:`materials.glints.pndf_drjit.lobes_pndf`) and the
float64 numpy reference (:func:`materials.glints.footprint.yan_pndf`).

Tolerance: the hierarchy sums the brute force's terms (the same code, so the same float32
values) except those it proves negligible, each below ``exp(-k^2 / 2)`` of its own peak, so
``|hier - brute| <= truncation_bound`` (``exp(-k^2 / 2)`` times the sum of the box's peaks,
in float64) plus float32 rounding of the two sums, which add the same positive terms in a
different order: at most a few thousand terms here, whose rounding grows like
``sqrt(N) eps`` (about 1e-5 relative); 1e-4 of the value leaves a factor of ten. At
``k = 2`` the same bound must hold while the hierarchy visibly drops mass (so the test can
fail, and the bound is what holds it).
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from materials.glints.examples import procedural_example
from materials.glints.footprint import yan_pndf
from materials.glints.lobes import Lobes, make_lobes
from materials.glints.pndf_drjit import Sym2, jit_lobes, lobes_pndf
from materials.glints.pndf_yan_hier import (
    bounds_bytes,
    build_bounds,
    hier_pndf,
    hier_pndf_stats,
    jit_bounds,
    truncation_bound,
)
from materials.glints.surface import Distribution, Surface, export_normal_map

#: float32 rounding of two sums of the same positive terms in different orders (docstring).
RTOL = 1e-4
#: Footprints ``(centre, sigma_x, sigma_y, correlation)`` in map texels: below a texel,
#: a few texels, anisotropic and correlated, across the map's periodic edge, wider than
#: the map.
FOOTPRINTS = [
    ((20.3, 31.7), 0.4, 0.4, 0.0),
    ((11.1, 40.2), 2.5, 1.5, 0.5),
    ((44.6, 3.2), 5.0, 2.0, -0.7),
    ((1.5, 46.9), 3.0, 3.0, 0.2),
    ((24.0, 24.0), 14.0, 9.0, 0.3),
]


@pytest.fixture(scope="module")
def lobes() -> Lobes:
    """A 48-texel export (not a power of two: the grid is padded) of a tiled scratches
    example, 2 x 2 lobes per texel."""
    normals = procedural_example("scratches", 16, np.random.default_rng(4))
    explicit = export_normal_map(Surface(normals, Distribution()), 48, oversample=1)
    return make_lobes(explicit, rate=2, sigma_r=0.02)


def _queries(n: int) -> np.ndarray:
    rng = np.random.default_rng(11)
    return np.concatenate([rng.normal(0.0, 0.2, (n - 2, 2)), [[0.0, 0.0], [0.9, -0.9]]]).astype(
        np.float32
    )


def _footprint(
    mi: types.ModuleType, fp: tuple, m: int
) -> tuple[np.ndarray, np.ndarray, tuple, Sym2]:  # type: ignore[type-arg]
    (cx, cy), sx, sy, rho = fp
    cov = np.array([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]])

    def full(v: float) -> object:
        return mi.Float(np.full(m, v, np.float32))

    return (
        np.array([cx, cy]),
        cov,
        (full(cx), full(cy)),
        Sym2(full(cov[0, 0]), full(cov[0, 1]), full(cov[1, 1])),
    )


@pytest.mark.parametrize("fp", FOOTPRINTS)
def test01_hierarchy_equals_brute_force(
    mi: types.ModuleType,
    lobes: Lobes,
    fp: tuple,  # type: ignore[type-arg]
) -> None:
    """The same P-NDF as the brute force (and as the float64 reference) to the truncation
    bound plus float32 rounding (module docstring), at 202 half vectors."""
    q = _queries(202)
    c, cov, jc, jcov = _footprint(mi, fp, len(q))
    jq = (mi.Float(q[:, 0]), mi.Float(q[:, 1]))
    jl = jit_lobes(mi, lobes)
    bounds = build_bounds(lobes)
    brute = np.asarray(lobes_pndf(mi, jl, jc, jcov, jq).numpy(), np.float64)
    hier = np.asarray(hier_pndf(mi, jl, jit_bounds(mi, bounds), jc, jcov, jq).numpy(), np.float64)
    ref = yan_pndf(lobes, c, cov, q.astype(np.float64))
    drop = truncation_bound(lobes, c, cov, bounds.sigmas)
    assert np.abs(hier - brute).max() <= drop + RTOL * np.abs(brute).max() + 1e-6
    np.testing.assert_allclose(hier, brute, rtol=RTOL, atol=drop + 1e-6)
    # The brute force's own float32 error against float64, plus what the hierarchy drops.
    own = np.abs(brute - ref)
    assert np.all(np.abs(hier - ref) <= own + drop + RTOL * np.abs(ref) + 1e-6)
    assert brute.max() > 1.0  # the queries reach the microstructure's normals


def test02_bound_holds_where_truncation_bites(mi: types.ModuleType, lobes: Lobes) -> None:
    """At ``k = 2`` the hierarchy drops visible mass (relative 1e-3 or more somewhere), and
    still within :func:`truncation_bound` (plus rounding)."""
    q = _queries(202)
    fp = FOOTPRINTS[2]
    c, cov, jc, jcov = _footprint(mi, fp, len(q))
    jq = (mi.Float(q[:, 0]), mi.Float(q[:, 1]))
    jl = jit_lobes(mi, lobes)
    brute = np.asarray(lobes_pndf(mi, jl, jc, jcov, jq).numpy(), np.float64)
    loose = jit_bounds(mi, build_bounds(lobes, sigmas=2.0))
    hier = np.asarray(hier_pndf(mi, jl, loose, jc, jcov, jq).numpy(), np.float64)
    diff = np.abs(hier - brute)
    assert diff.max() > 1e-3 * brute.max()
    assert np.all(hier <= brute * (1 + RTOL) + 1e-6)  # it only drops positive terms
    assert diff.max() <= truncation_bound(lobes, c, cov, 2.0) + RTOL * brute.max()


def test03_it_skips(mi: types.ModuleType, lobes: Lobes) -> None:
    """Leaf blocks summed are fewer than the support box's blocks: at a half vector no
    lobe reaches (outside the unit disc), none (and the P-NDF is 0); near the flat
    surface's normal (most of a scratched map), all of them; at a scratch's slope, fewer."""
    fp = ((24.0, 24.0), 6.0, 6.0, 0.0)
    q = np.array([[3.0, -3.0], [0.0, 0.0], [-0.15, 0.1]], np.float32)
    _, _, jc, jcov = _footprint(mi, fp, len(q))
    jq = (mi.Float(q[:, 0]), mi.Float(q[:, 1]))
    jl = jit_lobes(mi, lobes)
    bounds = jit_bounds(mi, build_bounds(lobes))
    value, nodes, leaves = hier_pndf_stats(mi, jl, bounds, jc, jcov, jq)
    # The brute force's box: 3.5 sigma plus 5 sigma_h each side; the 2 x 2 blocks it meets.
    half = 3.5 * 6.0 + 5.0 * lobes.sigma_h
    per_axis = math.floor(24.0 + half) // 2 - math.floor(24.0 - half) // 2 + 1
    blocks = per_axis**2
    got = leaves.numpy()
    assert got[0] == 0 and value.numpy()[0] == 0.0
    assert got[1] == blocks
    assert 0 < got[2] < blocks
    assert np.all(nodes.numpy() < 2 * blocks)


def test04_bounds_hold_every_lobe(lobes: Lobes) -> None:
    """Min-max: each level-0 block's bounds hold its lobes' ``s -/+ k sigma_a``, each parent
    holds its children, and padding blocks hold nothing."""
    b = build_bounds(lobes, sigmas=3.0)
    n, k2 = lobes.size, lobes.rate**2
    s = lobes.s.reshape(n, n, k2, 2)
    jac = lobes.jac.reshape(n, n, k2, 2, 2)
    sig = np.sqrt(lobes.sigma_r**2 + lobes.sigma_h**2 * np.sum(jac * jac, axis=-1))
    lvl0 = b.levels[0].astype(np.float64)
    for ty in range(0, n, 7):
        for tx in range(0, n, 5):
            blk = lvl0[:, ty // 2, tx // 2]
            assert np.all(s[ty, tx] - 3.0 * sig[ty, tx] >= blk[0:2])
            assert np.all(s[ty, tx] + 3.0 * sig[ty, tx] <= blk[2:4])
            assert np.all(np.abs(jac[ty, tx]).sum(axis=-1) <= blk[4:6])
    for child, parent in zip(b.levels[:-1], b.levels[1:], strict=True):
        up = np.repeat(np.repeat(parent, 2, axis=1), 2, axis=2)
        assert np.all(child[0:2] >= up[0:2]) and np.all(child[2:6] <= up[2:6])
    pad = lvl0[:, :, n // 2 :]  # 48 texels = 24 blocks of a 32-block grid
    assert pad.shape[2] == 8 and np.all(np.isinf(pad[0:4]))
    assert b.levels[-1].shape == (6, 1, 1)


def test05_bad_input(mi: types.ModuleType, lobes: Lobes) -> None:
    with pytest.raises(ValueError, match="truncation"):
        build_bounds(lobes, sigmas=0.0)
    with pytest.raises(ValueError, match="leaf"):
        build_bounds(lobes, leaf=3)
    other = make_lobes(np.dstack([np.zeros((8, 8, 2)), np.ones((8, 8))]), rate=1)
    jb = jit_bounds(mi, build_bounds(other))
    z = mi.Float(0.0)
    with pytest.raises(ValueError, match="8-texel map"):
        hier_pndf(mi, jit_lobes(mi, lobes), jb, (z, z), Sym2(z + 1, z, z + 1), (z, z))


@pytest.mark.parametrize("n", [1, 7, 48, 64])
def test06_bounds_bytes(n: int) -> None:
    """The memory column's figure is the built hierarchy's size."""
    normals = np.dstack([np.zeros((n, n, 2)), np.ones((n, n))])
    for leaf in (1, 2, 4):
        built = build_bounds(make_lobes(normals, rate=1), leaf=leaf)
        assert bounds_bytes(n, leaf) == built.nbytes
