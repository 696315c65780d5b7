"""The hierarchical visibility march (``march.py``) against the plain and a brute-force march.

References: (1) the plain march of ``integrand.visibility`` (every step tested), which the
hierarchy must reproduce, since it only skips test points it proves clear; (2) a
brute-force fine march (steps of 0.002 cells, up to 1024 per ray, every step tested), the
reference for what the default step resolves; (3) the height field itself at dense random
points, for the mip-map's bounds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from materials.fabric import yarn
from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.array_ops import NumpyOps
from materials.fabric.integrand import RayQuery, visibilities, visibility
from materials.fabric.march import LEVELS, max_mip, upload
from materials.fabric.params import FabricParams
from materials.fabric.patterns import PATTERNS

OPS = NumpyOps()


def _rays(geo: yarn.YarnGeometry, m: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    tab = yarn.tables(OPS, geo)
    s = rng.uniform(-2, 3, m).astype(np.float32)  # also outside [0, 1): periodic tile
    t = rng.uniform(-2, 3, m).astype(np.float32)
    h0 = yarn.height(OPS, geo, tab, s, t)
    theta = np.radians(rng.uniform(0, 89, m))
    phi = rng.uniform(0, 2 * math.pi, m)
    w = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return s, t, h0, w.astype(np.float32), rng.uniform(0, 1, m).astype(np.float32)


def _counting(ops: NumpyOps) -> list[int]:
    """Make ``ops.march`` count body evaluations (element-iterations); returns the counter."""
    calls = [0]
    plain_march = NumpyOps.march

    def march(
        count: np.ndarray,
        max_steps: int,
        lanes: tuple[np.ndarray, ...],
        flag: np.ndarray,
        body: Callable[[np.ndarray, tuple[np.ndarray, ...]], tuple[np.ndarray, np.ndarray]],
    ) -> np.ndarray:
        def counted(k: np.ndarray, lane: tuple[np.ndarray, ...]) -> tuple[np.ndarray, np.ndarray]:
            calls[0] += len(k)
            return body(k, lane)

        return plain_march(ops, count, max_steps, lanes, flag, counted)

    ops.march = march  # type: ignore[method-assign]
    return calls


@pytest.mark.parametrize(("name", "beta"), [("plain", 1.0), ("twill_5x5", 0.7), ("satin_5x5", 1.5)])
def test01_hierarchical_equals_plain_march(name: str, beta: float) -> None:
    """Same steps, same jitter, same tolerance: the skipped points are provably clear, so
    the visibility is the plain march's, in fewer iterations."""
    params = FabricParams(PATTERNS[name], beta=beta, u_max_deg=30.0)
    geo = yarn.YarnGeometry.from_params(params)
    tab = yarn.tables(OPS, geo)
    s, t, h0, w, jit = _rays(geo, 20000, seed=11)
    ops = NumpyOps()
    calls = _counting(ops)
    plain = visibility(ops, geo, tab, s, t, h0, (w[0], w[1], w[2]), jit)
    n_plain = calls[0]
    calls[0] = 0
    mip = upload(ops, max_mip(geo))
    hier = visibility(ops, geo, tab, s, t, h0, (w[0], w[1], w[2]), jit, mip=mip)
    n_hier = calls[0]
    # float32 round-off in a jump's target index may move a test point by one step; none
    # of 20,000 rays differed here, allow 0.05 %.
    assert np.mean(plain != hier) <= 5e-4
    assert 0.05 < plain.mean() < 0.95  # both outcomes occur
    assert n_hier < 0.8 * n_plain, (n_hier, n_plain)


@pytest.mark.parametrize("name", ["twill_3x3", "satin_5x5"])
def test02_hierarchical_against_brute_force_fine_march(name: str) -> None:
    """Against a plain march at 0.002-cell steps (25x finer than the default): the default
    steps can miss occluders thinner than a step at grazing angles (integrand.py); agreement
    on at least 98 % of rays, the bar of the ray-cast test (test_identities.py)."""
    params = FabricParams(PATTERNS[name], beta=1.0, u_max_deg=30.0)
    geo = yarn.YarnGeometry.from_params(params)
    tab = yarn.tables(OPS, geo)
    s, t, h0, w, jit = _rays(geo, 4000, seed=5)
    mip = upload(OPS, max_mip(geo))
    hier = visibility(OPS, geo, tab, s, t, h0, (w[0], w[1], w[2]), jit, mip=mip)
    fine = visibility(OPS, geo, tab, s, t, h0, (w[0], w[1], w[2]), jit, step=0.002, max_steps=1024)
    agree = np.mean(hier == fine)
    assert agree >= 0.98, agree
    assert 0.05 < fine.mean() < 0.95
    # A finer hierarchical march converges to the same reference.
    hier_fine = visibility(
        OPS, geo, tab, s, t, h0, (w[0], w[1], w[2]), jit, step=0.002, max_steps=1024, mip=mip
    )
    assert np.mean(hier_fine != fine) <= 5e-4


def test03_mip_bounds_hold_at_random_points() -> None:
    """Every level bounds the height at dense random points of each texel (the reference is
    the height field itself), and a coarse texel bounds its children."""
    params = FabricParams(PATTERNS["twill_5x5"], beta=1.5, u_max_deg=45.0)
    geo = yarn.YarnGeometry.from_params(params)
    tab = yarn.tables(OPS, geo)
    mip = max_mip(geo)
    rng = np.random.default_rng(2)
    s, t = rng.uniform(0, 1, 400000), rng.uniform(0, 1, 400000)
    h = yarn.height(OPS, geo, tab, s.astype(np.float32), t.astype(np.float32))
    for i, n in enumerate(LEVELS):
        bound = mip.level(i)
        iy = np.minimum((t * geo.rows * n).astype(int), geo.rows * n - 1)
        ix = np.minimum((s * geo.cols * n).astype(int), geo.cols * n - 1)
        assert np.all(h <= bound[iy, ix]), i
        if i:
            child = mip.level(i - 1)
            up = np.kron(bound, np.ones((2, 2), dtype=np.float32))
            assert np.all(child <= up)
    # Tight, as the bound is the height at each texel's highest point (march.py): within
    # 0.01 cells of the random points' maximum per texel, on average (about 250 points per
    # texel fall short of the true maximum by less than that).
    finest = mip.level(0)
    iy = np.minimum((t * geo.rows * LEVELS[0]).astype(int), geo.rows * LEVELS[0] - 1)
    ix = np.minimum((s * geo.cols * LEVELS[0]).astype(int), geo.cols * LEVELS[0] - 1)
    sampled = np.zeros_like(finest)
    np.maximum.at(sampled, (iy, ix), h)
    assert float(np.mean(finest - sampled)) < 0.01


def test04_estimates_agree_between_marches() -> None:
    """The estimator's output with each march: equal up to float32 round-off."""
    params = FabricParams(PATTERNS["twill_3x3"], beta=1.0, u_max_deg=30.0)
    rng = np.random.default_rng(4)
    wi = rng.normal(size=(8, 3))
    wo = rng.normal(size=(8, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    q = FootprintQueries(rng.uniform(0, 1, (8, 2)), rng.uniform(0.2, 2, 8), wi, wo)
    a = estimate(params, q, samples=512, march="plain")
    for march in ("hierarchical", "batched"):
        b = estimate(params, q, samples=512, march=march)  # type: ignore[arg-type]
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(b.area, a.area, rtol=1e-5, atol=1e-7)
    # The Dr.Jit kernel (8 samples per lane with the batched march) against its plain march.
    c = estimate(params, q, samples=512, march="plain", backend="drjit")
    d = estimate(params, q, samples=512, march="batched", backend="drjit")
    np.testing.assert_allclose(d.mean, c.mean, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(d.area, c.area, rtol=1e-5, atol=1e-7)


def test05_unknown_march_is_refused() -> None:
    params = FabricParams(PATTERNS["plain"])
    q = FootprintQueries(
        np.zeros((1, 2)), np.ones(1), np.array([[0, 0, 1.0]]), np.array([[0, 0, 1.0]])
    )
    with pytest.raises(ValueError, match="march must be one of"):
        estimate(params, q, samples=64, march="fast")  # type: ignore[arg-type]


@pytest.mark.parametrize("backend", ["numpy", "drjit"])
def test06_marches_in_one_loop_equal_separate_marches(backend: str) -> None:
    """``visibilities`` (all rays of an element in one loop, ``ArrayOps.march_many``)
    against one ``visibility`` call per ray on the same backend: the same step function
    on the same inputs, so the same outcomes (a float32 jump target may round differently
    inside a different kernel: allow 0.05 %, as test01). Rays without a march (``need``
    False) must come out visible, and a lane must go on to its next ray after a hit."""
    params = FabricParams(PATTERNS["twill_5x5"], beta=0.7, u_max_deg=30.0)
    geo = yarn.YarnGeometry.from_params(params)
    tab_np = yarn.tables(OPS, geo)
    rays_np = [_rays(geo, 8000, seed=20 + i) for i in range(4)]
    needs = [np.random.default_rng(30 + i).uniform(size=8000) < 0.8 for i in range(4)]
    if backend == "numpy":
        ops: object = OPS
        conv: Callable[[np.ndarray], object] = lambda a: a  # noqa: E731
    else:
        from materials.fabric.aggregate_drjit import DrJitOps

        dops = DrJitOps()
        ops, conv = dops, lambda a: dops.Float(np.ascontiguousarray(a, dtype=np.float32))  # noqa: E731
    tab = yarn.tables(ops, geo)  # type: ignore[arg-type]
    mip = upload(ops, max_mip(geo))  # type: ignore[arg-type]
    queries = []
    for (s, t, h0, w, jit), need in zip(rays_np, needs, strict=True):
        need_b = need if backend == "numpy" else dops.Float(need.astype(np.float32)) > 0.5
        queries.append(
            RayQuery(
                conv(s), conv(t), conv(h0), (conv(w[0]), conv(w[1]), conv(w[2])), conv(jit), need_b
            )
        )
    together = visibilities(ops, geo, tab, queries, mip=mip)  # type: ignore[arg-type]
    for q, v, need in zip(queries, together, needs, strict=True):
        alone = visibility(ops, geo, tab, q.s, q.t, q.h0, q.w, q.jitter, need=q.need, mip=mip)  # type: ignore[arg-type]
        a, b = np.asarray(alone), np.asarray(v)
        assert np.mean(a != b) <= 5e-4
        assert np.all(b[~need] == 1.0)
        assert 0.05 < b[need].mean() < 0.95  # both outcomes occur
    del tab_np
