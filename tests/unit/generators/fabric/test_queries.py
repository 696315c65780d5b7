"""The stratified query design of ``generate.fabric`` (Chen et al. 2024, Sec. 5.1).

Oracles: exact stratum counts over a complete round (each cell exactly once per round);
the concentric map's equal-area property (the fraction of uniform square points inside
radius r is r^2) and the cosine-weighted hemisphere it yields (E[z] = 2/3); independence of
how a query range is split.
"""

from __future__ import annotations

import numpy as np
import pytest

from generators.fabric import queries as fq

FULL = 20480  # lcm(64, 20, 4096): every factor completes its rounds


def _cells(d: np.ndarray) -> np.ndarray:
    """Invert the stratum map: the 8 x 8 cell of upper-hemisphere directions."""
    r = np.hypot(d[:, 0], d[:, 1])
    phi = np.arctan2(d[:, 1], d[:, 0])
    # Inverse concentric map (Shirley & Chiu), back to [-1, 1]^2.
    phi = np.where(phi < -np.pi / 4, phi + 2 * np.pi, phi)
    a = np.where(
        phi < np.pi / 4,
        r,
        np.where(
            phi < 3 * np.pi / 4,
            r * (np.pi / 2 - phi) * 4 / np.pi,
            np.where(phi < 5 * np.pi / 4, -r, r * (phi - 3 * np.pi / 2) * 4 / np.pi),
        ),
    )
    b = np.where(
        phi < np.pi / 4,
        r * phi * 4 / np.pi,
        np.where(
            phi < 3 * np.pi / 4, r, np.where(phi < 5 * np.pi / 4, r * (np.pi - phi) * 4 / np.pi, -r)
        ),
    )
    ix = np.clip(np.floor((a + 1) / 2 * 8), 0, 7).astype(int)
    iy = np.clip(np.floor((b + 1) / 2 * 8), 0, 7).astype(int)
    return iy * 8 + ix


def test01_complete_round_visits_every_stratum_equally() -> None:
    q = fq.design_queries(7, 0, FULL)
    cx = np.floor(q.centre * 8).astype(int)
    counts = np.bincount(cx[:, 1] * 8 + cx[:, 0], minlength=64)
    assert np.all(counts == FULL // 64)
    lo, hi = fq.size_edges()
    assert len(lo) == 20 and lo[0] == 0 and hi[9] == 1 and hi[-1] == 5
    size_cell = np.searchsorted(hi, q.size, side="right")
    assert np.all(np.bincount(size_cell, minlength=20) == FULL // 20)
    assert np.count_nonzero(q.size[size_cell < 10] <= 1) == FULL // 2
    wi_up = q.wi * np.array([1.0, 1.0, 1.0])
    wi_up[:, 2] = np.abs(wi_up[:, 2])  # BTDF pairs mirror wi's stratum below
    pair = _cells(wi_up) * 64 + _cells(q.wo)
    assert np.all(np.bincount(pair, minlength=4096) == FULL // 4096)
    assert np.count_nonzero(q.wi[:, 2] < 0) == FULL // 2


def test02_directions_are_valid_and_cosine_distributed() -> None:
    q = fq.design_queries(3, 0, FULL, btdf_fraction=0.25)
    for w in (q.wi, q.wo):
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    assert np.all(q.wo[:, 2] > 0) and np.all(q.wi[:, 2] != 0)
    assert np.count_nonzero(q.wi[:, 2] < 0) == 5 * round(4096 * 0.25)
    assert abs(np.abs(q.wo[:, 2]).mean() - 2 / 3) < 0.005  # cosine-weighted: E[z] = 2/3
    assert np.all((q.centre >= 0) & (q.centre < 1))


def test03_concentric_map_is_equal_area() -> None:
    rng = np.random.default_rng(0)
    u = rng.random((2, 200_000))
    x, y = fq.concentric_disk(u[0], u[1])
    r2 = x * x + y * y
    assert r2.max() <= 1.0 + 1e-12
    for r in (0.3, 0.6, 0.9):
        assert abs(np.mean(r2 < r * r) - r * r) < 0.005
    x0, y0 = fq.concentric_disk(np.array([0.5]), np.array([0.5]))
    assert x0[0] == 0 and y0[0] == 0


def test04_ranges_do_not_depend_on_splitting() -> None:
    whole = fq.design_queries(11, 0, 9000)
    part = fq.design_queries(11, 4000, 4500)
    for name in ("centre", "size", "wi", "wo"):
        np.testing.assert_array_equal(getattr(part, name), getattr(whole, name)[4000:8500])
    other = fq.design_queries(12, 0, 100)
    assert not np.array_equal(other.centre, whole.centre[:100])


def test05_bad_arguments() -> None:
    with pytest.raises(ValueError, match="btdf_fraction"):
        fq.design_queries(0, 0, 10, btdf_fraction=1.5)
    with pytest.raises(ValueError, match="first and count"):
        fq.design_queries(0, -1, 10)
    assert len(fq.design_queries(0, 5, 0)) == 0


def test06_log_uniform_sizes() -> None:
    q = fq.design_queries(7, 0, FULL, sizes="log_uniform")
    ref = fq.design_queries(7, 0, FULL)
    # Only the sizes change: centres and directions are the same design.
    np.testing.assert_array_equal(q.centre, ref.centre)
    np.testing.assert_array_equal(q.wi, ref.wi)
    assert q.size.min() >= fq.LOG_SIZE_MIN and q.size.max() <= 5.0
    # 20 strata equal in ln size, each visited FULL / 20 times.
    u = np.log(q.size / fq.LOG_SIZE_MIN) / np.log(5.0 / fq.LOG_SIZE_MIN)
    assert np.all(np.bincount(np.floor(u * 20).astype(int), minlength=20) == FULL // 20)
    # Log-uniform within strata: the fraction in [0.03, 0.1] tile is ln(10/3) / ln(500).
    frac = np.mean((q.size >= 0.03) & (q.size < 0.1))
    assert abs(frac - np.log(10 / 3) / np.log(500)) < 0.01
    assert np.mean(ref.size < 0.1) == pytest.approx(0.05)
    with pytest.raises(ValueError, match="sizes"):
        fq.design_queries(0, 0, 10, sizes="uniform")
