"""One-blob encoding and footprint normalisation (:mod:`models.fabric.encoding`).

Oracles: hand-computed values of ``exp(-0.5 ((u - c_i) bins)^2)`` (Mueller et al. 2019's
one-blob with a Gaussian of width 1/bins at the bin centres); properties a one-blob must
have (bounded, peak in the bin containing ``u``, peak position monotone in ``u``, near
constant total mass away from the edges); the numpy, torch and Dr.Jit backends agreeing.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from models.fabric.encoding import (
    BINS,
    NUMPY_OPS,
    drjit_ops,
    one_blob,
    size_unit,
    spatial_features,
    spatial_features_numpy,
    torch_ops,
    wrap_unit,
)


def blob(u: np.ndarray) -> np.ndarray:
    return np.stack(one_blob(NUMPY_OPS, np.asarray(u, np.float64)), axis=-1)


def test01_hand_computed_values() -> None:
    e = blob(np.array([0.5, 0.0]))
    # u = 0.5 sits between centres 3 and 4 (0.4375, 0.5625): (0.0625 * 8)^2 / 2 = 1/8.
    assert math.isclose(e[0, 3], math.exp(-0.125), rel_tol=1e-12)
    assert math.isclose(e[0, 4], math.exp(-0.125), rel_tol=1e-12)
    assert math.isclose(e[0, 2], math.exp(-0.5 * 1.5**2), rel_tol=1e-12)
    # u = 0: distance to centre i is (i + 0.5) / 8, i.e. (i + 0.5) bin widths.
    for i in range(BINS):
        assert math.isclose(e[1, i], math.exp(-0.5 * (i + 0.5) ** 2), rel_tol=1e-12)


def test02_peak_in_own_bin_monotone_and_bounded() -> None:
    u = np.linspace(0.0, 0.999, 2001)
    e = blob(u)
    assert e.shape == (2001, BINS)
    assert np.all(e > 0) and np.all(e <= 1)
    peak = e.argmax(axis=1)
    np.testing.assert_array_equal(peak, np.floor(u * BINS).astype(int))
    assert np.all(np.diff(peak) >= 0)
    assert np.all(e.max(axis=1) >= math.exp(-1 / 8) - 1e-12)
    # Partition-like: where the kernel's +-3 bins fit inside, the total is that of the
    # Gaussian sampled at unit spacing, sum_k exp(-k^2 / 2) = sqrt(2 pi) = 2.5066 (1 %).
    inner = (u >= 2.5 / BINS) & (u <= 1 - 2.5 / BINS)
    mass = e[inner].sum(axis=1)
    assert np.all(np.abs(mass - math.sqrt(2 * math.pi)) < 0.025)


def test03_footprint_normalisation() -> None:
    s = np.array([0.0, 0.5, 1.0, 3.0, 5.0, 9.0, -1.0])
    np.testing.assert_allclose(size_unit(NUMPY_OPS, s), [0, 0.25, 0.5, 0.75, 1, 1, 0])
    x = np.array([1.25, -0.25, 0.0, 0.999])
    np.testing.assert_allclose(wrap_unit(NUMPY_OPS, x), [0.25, 0.75, 0.0, 0.999], atol=1e-12)
    f = spatial_features_numpy(np.array([0.2, 1.2]), np.array([0.7, -0.3]), np.array([2.0, 2.0]))
    assert f.shape == (2, 3 * BINS) and f.dtype == np.float32
    # Periodic in the centre. float32: 1.2 - 1 and 0.2 round apart by 5e-8, times 8 bins
    # times the Gaussian's largest slope (0.61) is 2.4e-7 (measured 2.3e-7), plus an ulp of
    # exp; a centre that is not wrapped moves features by O(0.1).
    np.testing.assert_allclose(f[0], f[1], atol=1e-6)


def test04_backends_agree(mitsuba_llvm: None) -> None:
    import drjit as dr
    import drjit.llvm as llvm

    rng = np.random.default_rng(0)
    cx, cy = rng.uniform(-2, 3, 500), rng.uniform(-2, 3, 500)
    size = rng.uniform(0, 6, 500)
    ref = spatial_features_numpy(cx, cy, size)
    t = spatial_features(
        torch_ops(), *(torch.from_numpy(a.astype(np.float32)) for a in (cx, cy, size))
    )
    # float32 in three backends, each with its own exp and operation order: an ulp of the
    # distance to a bin (6e-8) times 8 bins times the Gaussian's largest slope (0.61), plus
    # a few ulps of exp, is under 1e-6 (measured 1.2e-7); a wrong bin moves a feature O(0.1).
    np.testing.assert_allclose(torch.stack(t, 1).numpy(), ref, atol=2e-6)
    d = spatial_features(drjit_ops(), *(llvm.Float(a.astype(np.float32)) for a in (cx, cy, size)))
    dr.eval(d)
    np.testing.assert_allclose(np.stack([x.numpy() for x in d], 1), ref, atol=2e-6)
