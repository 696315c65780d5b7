"""BRDF-space metrics and the scoring pairs (evaluators/metrics/brdf.py).

Oracles: Eq. 6 of the hybrid-BRDF paper evaluated by hand and by an element-by-element loop
written here; invariances (identity, symmetry, common scale, bounds, integer weights as
repeated pairs); the analytic moments of the documented direction distributions, and a
chi-square test of ``cos^2 theta`` (uniform in [0, 1] under cosine weighting); error paths.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from evaluators.metrics.brdf import (
    DEFAULT_PAIRS,
    PAIRS_SEED,
    BrdfSampler,
    TableSampler,
    brdf_mae,
    direction_pairs,
    sample_brdf,
    smape,
    smape_floor,
)
from storage.formats.merl import MerlTable


def smape_by_loop(ref: np.ndarray, test: np.ndarray) -> float:
    """Eq. 6 term by term, plain Python floats: 2/(N C) sum |a - b| / (|a| + |b|), 0/0 = 0."""
    total, count = 0.0, 0
    for a, b in zip(np.ravel(ref).tolist(), np.ravel(test).tolist(), strict=True):
        den = abs(a) + abs(b)
        total += abs(a - b) / den if den > 0 else 0.0
        count += 1
    return 2.0 * total / count


def brdf_values(seed: int, n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Two (n, 3) arrays of positive BRDF-like values over several decades, some zeros."""
    rng = np.random.default_rng(seed)
    a = 10.0 ** rng.uniform(-3, 2, (n, 3))
    b = a * rng.lognormal(0.0, 0.5, (n, 3))
    a[0, 0] = b[0, 0] = 0.0  # 0/0
    b[1, 1] = 0.0  # one side zero: a term of 1
    return a, b


# -- SMAPE: closed forms ---------------------------------------------------------------------


def test01_smape_hand_computed() -> None:
    ref = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 4.0]])
    test = np.array([[1.0, 1.0, 1.0], [0.0, 2.0, 4.0]])
    # Terms: 0, 1/3, 2/4 | 0/0 := 0, 2/2, 0 -> sum 11/6; SMAPE = 2/6 * 11/6 = 11/18.
    assert smape(ref, test) == pytest.approx(11.0 / 18.0, rel=1e-15)
    assert brdf_mae(ref, test) == pytest.approx((0 + 1 + 2 + 0 + 2 + 0) / 6.0, rel=1e-15)


def test02_smape_matches_a_term_by_term_loop() -> None:
    for seed in range(5):
        a, b = brdf_values(seed)
        assert smape(a, b) == pytest.approx(smape_by_loop(a, b), rel=1e-12)
        assert smape(a[:, 0], b[:, 0]) == pytest.approx(smape_by_loop(a[:, 0], b[:, 0]), rel=1e-12)
        mae_loop = sum(abs(x - y) for x, y in zip(a.ravel(), b.ravel(), strict=True)) / a.size
        assert brdf_mae(a, b) == pytest.approx(mae_loop, rel=1e-12)


def test03_smape_channels_are_averaged() -> None:
    a, b = brdf_values(7)
    per_channel = [smape(a[:, c], b[:, c]) for c in range(3)]
    assert smape(a, b) == pytest.approx(float(np.mean(per_channel)), rel=1e-12)


def test04_integer_weights_repeat_pairs() -> None:
    a, b = brdf_values(3, n=6)
    w = np.array([2, 1, 0, 3, 1, 1])
    rep = np.repeat(np.arange(6), w)
    assert smape(a, b, weights=w) == pytest.approx(smape(a[rep], b[rep]), rel=1e-12)
    assert brdf_mae(a, b, weights=w) == pytest.approx(brdf_mae(a[rep], b[rep]), rel=1e-12)
    assert smape(a, b, weights=np.ones(6)) == pytest.approx(smape(a, b), rel=1e-12)


def test05_eps_floors_the_denominator() -> None:
    a, b = np.array([1e-9, 1.0]), np.array([0.0, 1.0])
    assert smape(a, b) == pytest.approx(1.0)  # (2/2) * (1 + 0)
    assert smape(a, b, eps=1e-6) == pytest.approx(2.0 / 2.0 * (1e-9 / (1e-9 + 1e-6)))
    assert smape(a, b, eps=0.0) == smape(a, b)


# -- SMAPE: invariances ----------------------------------------------------------------------


def test06_identity_symmetry_and_scale() -> None:
    a, b = brdf_values(11)
    assert smape(a, a) == 0.0 and brdf_mae(a, a) == 0.0
    assert smape(a, b) == smape(b, a)  # Eq. 6 is symmetric term by term
    assert brdf_mae(a, b) == brdf_mae(b, a)
    # A common positive scale leaves every term unchanged (so f and cos(theta_i) f agree) ...
    cos_i = np.random.default_rng(0).uniform(0.05, 1.0, (len(a), 1))
    assert smape(a * 7.5, b * 7.5) == pytest.approx(smape(a, b), rel=1e-12)
    assert smape(a * cos_i, b * cos_i) == pytest.approx(smape(a, b), rel=1e-12)
    # ... MAE scales with it, and scaling one argument is an error SMAPE sees.
    assert brdf_mae(a * 7.5, b * 7.5) == pytest.approx(7.5 * brdf_mae(a, b), rel=1e-12)
    assert smape(a, 2.0 * a) == pytest.approx(2.0 * (1.0 / 3.0) * (a.size - 1) / a.size)


def test07_bounds_zero_to_two() -> None:
    a, b = brdf_values(5)
    assert 0.0 < smape(a, b) < 2.0
    pos = np.array([[1.0, 2.0, 3.0]])
    assert smape(pos, np.zeros_like(pos)) == 2.0  # one side zero everywhere
    assert smape(pos, -pos) == 2.0  # opposite signs
    assert smape(np.zeros((4, 3)), np.zeros((4, 3))) == 0.0  # all 0/0
    huge = np.array([1e300, 1e-300])
    assert 0.0 <= smape(huge, huge[::-1]) <= 2.0


# -- SMAPE and MAE: refusals -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("ref", "test", "kwargs", "message"),
    [
        (np.ones((4, 3)), np.ones((4, 2)), {}, "differ in shape"),
        (np.ones((2, 2, 3)), np.ones((2, 2, 3)), {}, r"\(N,\) or \(N, C\)"),
        (np.ones((0, 3)), np.ones((0, 3)), {}, "non-empty"),
        (np.array([1.0, np.nan]), np.ones(2), {}, "reference has 1 non-finite"),
        (np.ones(2), np.array([np.inf, 1.0]), {}, "test has 1 non-finite"),
        (np.array(["a", "b"]), np.array(["a", "b"]), {}, "must be numeric"),
        (np.ones((4, 3)), np.ones((4, 3)), {"weights": np.ones(3)}, r"weights must have shape"),
        (np.ones(4), np.ones(4), {"weights": -np.ones(4)}, "non-negative"),
        (np.ones(4), np.ones(4), {"weights": np.zeros(4)}, "sum to zero"),
        (np.ones(4), np.ones(4), {"weights": np.full(4, np.nan)}, "finite"),
    ],
)
def test08_refusals(ref: np.ndarray, test: np.ndarray, kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        smape(ref, test, **kwargs)
    with pytest.raises(ValueError, match=message):
        brdf_mae(ref, test, **kwargs)


def test09_smape_refuses_bad_eps() -> None:
    for eps in (-1e-3, math.inf, math.nan):
        with pytest.raises(ValueError, match="eps must be"):
            smape(np.ones(3), np.ones(3), eps=eps)


# -- direction pairs -------------------------------------------------------------------------


def test10_pairs_are_unit_upper_hemisphere_and_deterministic() -> None:
    wi, wo = direction_pairs(5000)
    for w in (wi, wo):
        assert w.shape == (5000, 3) and w.dtype == np.float64
        np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
        assert np.all(w[:, 2] > 0)
    again = direction_pairs(5000, seed=PAIRS_SEED, distribution="cosine")
    assert np.array_equal(wi, again[0]) and np.array_equal(wo, again[1])
    other = direction_pairs(5000, seed=PAIRS_SEED + 1)
    assert not np.array_equal(wi, other[0])
    assert DEFAULT_PAIRS == 10**6


@pytest.mark.parametrize(
    ("distribution", "mean_cos", "mean_cos2"),
    [("cosine", 2.0 / 3.0, 1.0 / 2.0), ("uniform", 1.0 / 2.0, 1.0 / 3.0)],
)
def test11_pair_moments_match_the_distribution(
    distribution: str, mean_cos: float, mean_cos2: float
) -> None:
    # cosine: pdf cos/pi -> E[cos] = int cos^2 sin dtheta * 2 = 2/3, E[cos^2] = 1/2;
    # uniform: pdf 1/(2 pi) -> E[cos] = 1/2, E[cos^2] = 1/3.
    n = 200_000
    wi, wo = direction_pairs(n, seed=1, distribution=distribution)  # type: ignore[arg-type]
    se = math.sqrt((mean_cos2 - mean_cos**2) / n)
    for w in (wi, wo):
        assert abs(w[:, 2].mean() - mean_cos) < 5 * se
        assert abs((w[:, 2] ** 2).mean() - mean_cos2) < 0.005
        assert abs(w[:, 0].mean()) < 0.005 and abs(w[:, 1].mean()) < 0.005  # azimuth uniform
    assert abs(np.corrcoef(wi[:, 2], wo[:, 2])[0, 1]) < 0.01  # wi and wo independent


def test12_cosine_pairs_chi_square() -> None:
    # Under pdf cos(theta)/pi, cos^2(theta) is uniform on [0, 1] and phi uniform on [0, 2 pi).
    wi, _ = direction_pairs(100_000, seed=3)
    for values in (wi[:, 2] ** 2, (np.arctan2(wi[:, 1], wi[:, 0]) % (2 * np.pi)) / (2 * np.pi)):
        counts, _ = np.histogram(values, bins=40, range=(0.0, 1.0))
        assert stats.chisquare(counts).pvalue > 1e-3


def test13_pairs_refusals() -> None:
    for n in (0, -5, 2.5, True):
        with pytest.raises(ValueError, match="positive integer"):
            direction_pairs(n)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="unknown distribution 'sphere'"):
        direction_pairs(10, distribution="sphere")  # type: ignore[arg-type]


# -- samplers --------------------------------------------------------------------------------


def test14_table_sampler_and_chunking() -> None:
    rgb = np.empty((90, 90, 180, 3))
    rgb[...] = [0.1, 0.2, 0.3]
    rgb[:, 60:] = -1.0  # theta_d >= 60 degrees missing
    sampler = TableSampler(MerlTable(rgb))
    assert isinstance(sampler, BrdfSampler)
    wi, wo = direction_pairs(3000, seed=2)
    whole = sample_brdf(sampler, wi, wo, chunk=10**6)
    assert np.array_equal(whole, sample_brdf(sampler, wi, wo, chunk=7))
    assert np.array_equal(whole, sample_brdf(sampler, wi, wo, chunk=100, workers=3))
    theta_d = np.arccos(np.clip(np.sum(wi * wo, axis=1), -1, 1)) / 2  # wi.wo = cos(2 theta_d)
    low, high = theta_d < np.radians(59), theta_d > np.radians(61)
    np.testing.assert_allclose(whole[low], np.broadcast_to([0.1, 0.2, 0.3], whole[low].shape))
    assert np.all(whole[high] == -1.0)


class Broken:
    """A sampler returning the wrong shape, or NaN."""

    def __init__(self, nan: bool) -> None:
        self.nan = nan

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        return np.full((len(wi), 3), np.nan) if self.nan else np.zeros((len(wi), 1))


def test15_sample_brdf_refusals() -> None:
    wi, wo = direction_pairs(10)
    with pytest.raises(ValueError, match=r"returned shape \(10, 1\) for 10 pairs"):
        sample_brdf(Broken(nan=False), wi, wo)
    with pytest.raises(ValueError, match="30 non-finite values"):
        sample_brdf(Broken(nan=True), wi, wo)
    with pytest.raises(ValueError, match=r"returned shape \(4, 1\) for 4 pairs"):
        sample_brdf(Broken(nan=False), wi, wo, chunk=4, workers=2)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        sample_brdf(Broken(nan=False), wi, wo[:5])
    with pytest.raises(ValueError, match="chunk and workers must be positive"):
        sample_brdf(Broken(nan=False), wi, wo, workers=0)


def test16_smape_floor_at_exact_zeros_hand_computed() -> None:
    """A table 0 at half the pairs and a model with a 0.001 tail there: Eq. 6 pays 2 at each
    zero, the floored variant |0.001| / (0.01 x mean 1) = 0.1."""
    ref = np.array([0.0, 0.0, 2.0, 2.0])
    test = np.array([0.001, 0.001, 2.0, 2.0])
    assert smape(ref, test) == pytest.approx(1.0)  # 2 x (1 + 1 + 0 + 0) / 4
    assert smape_floor(ref, test) == pytest.approx(2 * (0.1 + 0.1) / 4)
    # Only the pairs below the floor change: a 2.2 model at the 2.0 pairs adds Eq. 6's terms.
    test2 = np.array([0.001, 0.001, 2.2, 1.8])
    eq6_rest = 0.2 / 4.2 + 0.2 / 3.8
    assert smape_floor(ref, test2) == pytest.approx(2 * (0.2 + eq6_rest) / 4)
    # A tail above the floor is Eq. 6 there: 0.05 > 0.01, term 1.
    assert smape_floor(ref, np.array([0.05, 0.05, 2.0, 2.0])) == pytest.approx(1.0)
    # fraction moves the floor: 0.1 x mean 1 = 0.1, term 0.01.
    assert smape_floor(ref, test, fraction=0.1) == pytest.approx(2 * 0.02 / 4)


def test17_smape_floor_equals_eq6_without_zeros() -> None:
    """Tables without values near 0 give Eq. 6 to float tolerance, per channel and weighted."""
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.5, 3.0, size=(1000, 3))
    test = ref * rng.uniform(0.2, 5.0, size=(1000, 3))
    w = rng.uniform(0.0, 1.0, size=1000)
    assert smape_floor(ref, test) == pytest.approx(smape(ref, test), rel=1e-12)
    eq6 = smape(ref, test, weights=w)
    assert smape_floor(ref, test, weights=w) == pytest.approx(eq6, rel=1e-12)
    assert smape_floor(ref, ref) == 0.0


def test18_smape_floor_scale_channels_bounds_and_refusals() -> None:
    ref = np.array([[0.0, 1.0], [4.0, 0.0], [0.0, 0.0]])
    test = np.array([[0.01, 1.0], [4.0, 0.3], [0.0, 0.0]])
    # Channel 0: mean 4/3, floor 0.01333: term 0.01 / 0.01333 = 0.75. Channel 1: mean 1/3,
    # floor 0.00333 < 0.3: Eq. 6's 1.
    expected = 2 * (0.75 + 0 + 0 + 0 + 1 + 0) / 6
    assert smape_floor(ref, test) == pytest.approx(expected)
    assert smape_floor(7 * ref, 7 * test) == pytest.approx(expected)  # common scale
    # A reference channel 0 everywhere has no floor: Eq. 6 (0/0 = 0, else 1 per term).
    zero = np.zeros((2, 1))
    assert smape_floor(zero, np.array([[0.0], [1e-9]])) == pytest.approx(1.0)
    rng = np.random.default_rng(0)
    r, t = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    assert 0.0 <= smape_floor(r, t) <= smape(r, t) <= 2.0
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="fraction must be a finite positive"):
            smape_floor(ref, test, fraction=bad)
