"""The Dr.Jit LLVM estimator against the numpy reference (the twin of ``aggregate.py``).

Oracle: the numpy estimator on the same sample points. Both trace the same ``integrand``
code; the Dr.Jit kernel rebuilds the Sobol points itself (nets XOR per-query shifts), so
agreement also checks that reconstruction bit for bit. Float32 evaluation order differs
(fused multiply-adds, vectorised transcendental functions), so a visibility decision can
flip for a sample lying within round-off of a yarn's silhouette: we allow a few queries to
differ by one sample's weight.
"""

from __future__ import annotations

import numpy as np
import pytest

from materials.fabric.aggregate import FootprintQueries, estimate
from materials.fabric.params import FabricParams, sample_params
from materials.fabric.patterns import PATTERNS
from tests.helpers.slab_reference import direction


def mixed_queries(rng: np.random.Generator, count: int) -> FootprintQueries:
    wi = rng.normal(size=(count, 3))
    wi[: count // 4, 2] = -np.abs(wi[: count // 4, 2])  # a quarter lit from below
    wi[count // 4 :, 2] = np.abs(wi[count // 4 :, 2])
    wo = rng.normal(size=(count, 3))
    wo[:, 2] = np.abs(wo[:, 2]) + 0.05
    size = rng.uniform(0, 3, count)
    size[:4] = 0.0
    return FootprintQueries(
        rng.uniform(-4, 4, (count, 2)),
        size,
        wi / np.linalg.norm(wi, axis=1, keepdims=True),
        wo / np.linalg.norm(wo, axis=1, keepdims=True),
    )


@pytest.mark.parametrize(
    ("sampler", "kernel", "name"),
    [("sobol", "box", "twill_3x3"), ("independent", "gaussian", "satin_5x10")],
)
def test01_drjit_matches_numpy_on_the_same_points(sampler: str, kernel: str, name: str) -> None:
    params = sample_params(np.random.default_rng(11), name)
    q = mixed_queries(np.random.default_rng(12), 100)
    kw = {"samples": 256, "sampler": sampler, "kernel": kernel, "seed": 5, "chunk_queries": 64}
    ref = estimate(params, q, backend="numpy", **kw)  # type: ignore[arg-type]
    jit = estimate(params, q, backend="drjit", **kw)  # type: ignore[arg-type]
    scale = np.abs(ref.mean).max(axis=1, keepdims=True) + 1e-12
    rel = np.abs(jit.mean - ref.mean) / scale
    # One flipped visibility sample moves a query by about 1/N of its value.
    assert np.median(rel) < 1e-6
    assert np.mean(rel < 1e-4) > 0.95 and rel.max() < 4.0 / 256
    np.testing.assert_allclose(jit.area, ref.area, rtol=4.0 / 256)
    np.testing.assert_allclose(jit.area_in, ref.area_in, rtol=4.0 / 256, atol=1e-7)
    assert np.all(np.isfinite(jit.stderr)) and np.all(jit.stderr >= 0)


def test02_drjit_without_visibility_and_flat_yarns() -> None:
    params = FabricParams(PATTERNS["plain"], beta=(0.0, 0.0), alpha=(0.3, 0.6))  # type: ignore[arg-type]
    q = FootprintQueries(
        np.array([[0.1, 0.2], [0.5, 0.5]]),
        [2.0, 2.0],
        [direction(30, 10), direction(130, 40)],
        [direction(40, 200), direction(20, 90)],
    )
    for vis in (True, False):
        a = estimate(params, q, samples=512, backend="numpy", with_visibility=vis)
        b = estimate(params, q, samples=512, backend="drjit", with_visibility=vis)
        np.testing.assert_allclose(b.mean, a.mean, rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(b.stderr, a.stderr, rtol=1e-3, atol=1e-9)


@pytest.mark.parametrize(("sampler", "per_lane"), [("sobol", 1), ("sobol", 2), ("independent", 4)])
def test03_batched_march_matches_hierarchical(
    sampler: str, per_lane: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The batched march (several samples per SIMD lane, all their rays in one loop)
    against the hierarchical march of the same kernel code, one sample per lane: the same
    points and the same visibility, so the same estimates up to float32 round-off in a
    jump target (as ``test_march.py``), and float64 summation order. ``samples=8`` with 8
    replicates has blocks of one sample, fewer than ``per_lane``."""
    from materials.fabric import aggregate_drjit

    monkeypatch.setattr(aggregate_drjit, "LANE_SAMPLES", per_lane)
    params = sample_params(np.random.default_rng(21), "twill_3x3")
    q = mixed_queries(np.random.default_rng(22), 64)
    kw = {"samples": 512, "sampler": sampler, "seed": 3, "backend": "drjit"}
    a = estimate(params, q, march="hierarchical", **kw)  # type: ignore[arg-type]
    b = estimate(params, q, march="batched", **kw)  # type: ignore[arg-type]
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(b.area, a.area, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(b.area_in, a.area_in, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(b.stderr, a.stderr, rtol=1e-4, atol=1e-9)
    tiny = {"samples": 8, "replicates": 8, "sampler": sampler, "backend": "drjit"}
    c = estimate(params, q, march="hierarchical", **tiny)  # type: ignore[arg-type]
    d = estimate(params, q, march="batched", **tiny)  # type: ignore[arg-type]
    np.testing.assert_allclose(d.mean, c.mean, rtol=1e-5, atol=1e-9)
