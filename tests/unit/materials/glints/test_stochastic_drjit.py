"""The Dr.Jit twin of the stochastic distribution (``stochastic_pndf``) against the numpy
evaluator (:func:`materials.glints.footprint.tiny_pndf` on a stochastic surface, itself
tested against Fig. 3's rule point by point and against Yan's reference on the exported
microstructure in ``test_footprint.py``).

Tolerance: float32 against float64, a 2 x 2 Gauss-Legendre tile mass against 8 nodes, and
ownership decided in float32 (a tile centre or a seed within float32 rounding of a
sub-region's boundary may change owner): 1e-4 in relative L1 over 1,500 queries (measured
at most 2.2e-6).
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from materials.glints.examples import procedural_example
from materials.glints.footprint import TinyExample, tiny_pndf
from materials.glints.lobes import make_lobes
from materials.glints.ndf_maps import auto_extent, ndf_maps
from materials.glints.pndf_drjit import Sym2, jit_lobes, jit_maps, jit_placement, stochastic_pndf
from materials.glints.surface import Distribution, Surface


@pytest.fixture(scope="module")
def scratches() -> tuple[TinyExample, Surface]:
    normals = procedural_example("scratches", 16, np.random.default_rng(4))
    lobes = make_lobes(normals, rate=2, sigma_r=0.02)
    e = auto_extent(lobes)
    ex = TinyExample(lobes, ndf_maps(lobes, 48, e), e)
    surf = Surface(normals, Distribution(kind="stochastic", scale_range=(0.8, 1.25), seed=5))
    return ex, surf


def _floats(mi: types.ModuleType, v: float, n: int) -> object:
    return mi.Float(np.full(n, v, np.float32))


@pytest.mark.parametrize(
    ("centre", "sigma"), [((20.3, 31.7), 0.8), ((55.1, 12.4), 2.5), ((40.0, 40.0), 9.0)]
)
def test01_stochastic_twin_matches_numpy(
    mi: types.ModuleType,
    scratches: tuple[TinyExample, Surface],
    centre: tuple[float, float],
    sigma: float,
) -> None:
    """Below the finest tile (lobes, each seed owned by Fig. 3's rule), at level 0 and above
    (tiles owned by their centres), footprints meeting several overlapping instances."""
    ex, surf = scratches
    assert (
        len(surf.instances_near(np.array(centre) - 3.5 * sigma, np.array(centre) + 3.5 * sigma)) > 4
    )
    q = np.random.default_rng(2).uniform(-0.5, 0.5, (1500, 2))
    c = np.array(centre)
    cov = np.array([[1.0, 0.25], [0.25, 0.8]]) * sigma**2
    n = len(q)
    got = stochastic_pndf(
        mi,
        jit_maps(mi, ex.maps, ex.extent),
        jit_lobes(mi, ex.lobes),
        jit_placement(mi, surf),
        (_floats(mi, c[0], n), _floats(mi, c[1], n)),
        Sym2(_floats(mi, cov[0, 0], n), _floats(mi, cov[0, 1], n), _floats(mi, cov[1, 1], n)),
        (mi.Float(q[:, 0].astype(np.float32)), mi.Float(q[:, 1].astype(np.float32))),
    )
    got = np.asarray(got.numpy())
    want = tiny_pndf(ex, surf, c, cov, q)
    assert np.abs(want).sum() > 0
    err = np.abs(got - want).sum() / np.abs(want).sum()
    assert err < 1e-4, err


def test02_pndf_integrates_to_the_covered_mass(
    mi: types.ModuleType, scratches: tuple[TinyExample, Surface]
) -> None:
    """Placement statistics: each footprint point is owned by at most one instance (Fig. 3),
    so the P-NDF integrates over the normals to the footprint's mass on covered points
    (the NDF of one owner per point integrates to one). Expected: Monte Carlo over 40,000
    footprint samples of numpy's ``Surface.owner`` (standard error 0.2 %); integral: a
    400^2 grid over [-1, 1]^2. Tolerance 2 %: ownership is decided per tile (its centre),
    not per point, which moves mass across instance boundaries both ways."""
    ex, surf = scratches
    c = np.array([41.3, 37.9])
    cov = np.array([[1.0, 0.25], [0.25, 0.8]]) * 6.0**2
    u = np.random.default_rng(8).multivariate_normal(c, cov, 40_000)
    covered = np.zeros(len(u), dtype=bool)
    for _, mask in surf.owner(u):
        assert not np.any(covered & mask)  # one owner per point
        covered |= mask
    g = (np.arange(400) + 0.5) / 200.0 - 1.0
    qx, qy = (a.ravel().astype(np.float32) for a in np.meshgrid(g, g))
    m = len(qx)
    got = stochastic_pndf(
        mi,
        jit_maps(mi, ex.maps, ex.extent),
        jit_lobes(mi, ex.lobes),
        jit_placement(mi, surf),
        (_floats(mi, c[0], m), _floats(mi, c[1], m)),
        Sym2(_floats(mi, cov[0, 0], m), _floats(mi, cov[0, 1], m), _floats(mi, cov[1, 1], m)),
        (mi.Float(qx), mi.Float(qy)),
    )
    integral = float(np.asarray(got.numpy(), np.float64).sum() * (2.0 / 400) ** 2)
    assert 0.5 < covered.mean() <= 1.0
    assert abs(integral - covered.mean()) < 0.02, (integral, covered.mean())


def test03_candidates_hold_every_owner(scratches: tuple[TinyExample, Surface]) -> None:
    """The candidate lists (nearest first) give Fig. 3's owner of every point: the first
    candidate of its sub-cell that covers it is ``Surface.owner``'s instance."""
    from materials.glints.pndf_drjit import _candidates

    _, surf = scratches
    per, sp = surf.dist.period, surf.spacing
    reach = 0.75 * surf.n * max(surf.dist.scale_range) + surf.dist.jitter * sp
    dxs, dys, starts = _candidates(surf, reach)
    u = np.random.default_rng(3).uniform(-30.0, 130.0, (3000, 2))
    want = np.full((len(u), 2), 10**6)
    for inst, mask in surf.owner(u):
        want[mask] = np.floor(inst.centre / sp)  # the owner's cell (jitter < half a cell)
    cell = np.floor(u / sp).astype(int)
    quad = np.floor((u / sp - cell) * 2.0).astype(int)
    for i, p in enumerate(u):
        k = (((cell[i, 1] % per) * per + cell[i, 0] % per) * 2 + quad[i, 1]) * 2 + quad[i, 0]
        got = (10**6, 10**6)
        for j in range(starts[k], starts[k + 1]):
            cx, cy = cell[i, 0] + dxs[j], cell[i, 1] + dys[j]
            inst = surf._cell_instance(int(cx), int(cy))
            if inst.covers(p[None], surf.n)[0]:
                got = (cx, cy)
                break
        assert tuple(want[i]) == got, i
