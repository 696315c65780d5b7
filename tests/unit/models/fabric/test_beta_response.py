"""``held_out_beta``'s pieces: the material match and the slopes of ``beta_response``.

References: numpy's own least-squares line (``np.polyfit``) for the slopes; the match
rule written out (warp and weft equal, within 1e-6 of a listed value); for the slopes'
standard errors, brute force: the spread of the slope over many independent redraws of the
queries and the noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from jobapi.errors import JobFailed
from models.fabric.data import MaterialData
from models.fabric.report import (
    _held_out_rows,
    held_out_materials,
    response_slope,
    slope_with_stderr,
)


def material(name: str, beta: tuple[float, float]) -> MaterialData:
    empty = np.zeros((0, 8), np.float32)
    return MaterialData(
        name=name,
        pattern="plain",
        record={"beta": list(beta)},
        maps=np.zeros((6, 2, 2), np.float32),
        params=np.zeros(5, np.float32),
        query=empty,
        value=np.zeros((0, 4), np.float32),
        train=np.arange(0),
        test=np.arange(0),
    )


def test01_slopes_match_numpys_least_squares_line() -> None:
    rng = np.random.default_rng(3)
    beta = np.array([0.1, 0.34, 0.58, 0.82, 1.0])
    mean = rng.normal(size=(5, 5)) + 2.0 * beta[:, None] * np.arange(5)
    want = [np.polyfit(beta, mean[:, k], 1)[0] for k in range(5)]
    np.testing.assert_allclose(response_slope(beta, mean), want, rtol=1e-10, atol=1e-12)
    # A falling response has a negative slope.
    assert response_slope(beta, -beta[:, None])[0] == pytest.approx(-1.0)


def test02_materials_match_by_beta_and_bad_values_fail() -> None:
    # 0.1 + 0.9 * 2 / 3 is 0.7000000000000001 in float64: within the match tolerance.
    mats = [
        material("a", (0.1, 0.1)),
        material("b", (0.1 + 0.9 * 2 / 3, 0.1 + 0.9 * 2 / 3)),
        material("c", (0.7, 0.4)),  # warp and weft differ: never held out
        material("d", (1.0, 1.0)),
    ]
    assert held_out_materials(mats, [0.7]) == [1]
    assert held_out_materials(mats, [0.7, 1.0]) == [1, 3]
    with pytest.raises(JobFailed, match="held_out_beta: no material .* beta 0.5"):
        held_out_materials(mats, [0.5])
    with pytest.raises(JobFailed, match="every material"):
        held_out_materials(mats[:2], [0.1, 0.7])


BETA = np.array([0.1, 0.4, 0.7, 1.0])


def draw(rng: np.random.Generator, paired: bool, q: int = 200) -> list[np.ndarray]:
    """Values of 4 materials at ``q`` queries: a query-dependent level (the same query
    across materials when paired), a true slope of 0.02 per unit beta, and noise."""
    level = rng.lognormal(size=(q, 1))
    out = []
    for b in BETA:
        own = level if paired else rng.lognormal(size=(q, 1))
        out.append(own * (1.0 + 0.02 * b) + 0.01 * rng.normal(size=(q, 1)))
    return out


@pytest.mark.parametrize("paired", [True, False])
def test03_slope_standard_error_matches_the_spread_of_redraws(paired: bool) -> None:
    rng = np.random.default_rng(11)
    slopes, errors = [], []
    for _ in range(400):
        values = draw(rng, paired)
        slope, se = slope_with_stderr(BETA, values, paired)
        ref = np.polyfit(BETA, [v.mean() for v in values], 1)[0]
        assert slope[0] == pytest.approx(ref, rel=1e-9, abs=1e-12)
        slopes.append(slope[0])
        errors.append(se[0])
    # 400 redraws: the spread's own relative error is about 1/sqrt(2 * 400) = 3.5 %; 15 %.
    assert np.mean(errors) == pytest.approx(np.std(slopes, ddof=1), rel=0.15)
    if paired:  # pairing removes the query-to-query level from the difference
        unpaired = slope_with_stderr(BETA, draw(rng, False), False)[1][0]
        assert np.mean(errors) < 0.2 * unpaired


def test04_held_out_rows_align_shared_queries_by_shard_row() -> None:
    """Kept rows come in a per-name order (train, then test); scoring aligns them by shard
    row and keeps only the rows every material kept."""
    shard = np.arange(40, dtype=np.float32)[:, None] * np.ones((1, 8), np.float32)
    rows_a = np.arange(40)[::-1]
    rows_b = np.r_[5:40, 0:5]
    rows_b = rows_b[rows_b != 7]  # b did not keep shard row 7
    mats = [
        MaterialData(**{**material(n, (0.4, 0.4)).__dict__, "query": shard[r], "rows": r})
        for n, r in (("a", rows_a), ("b", rows_b))
    ]
    got = _held_out_rows(mats, [0, 1])
    a, b = (mats[i].query[r] for i, r in enumerate(got))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[:, 0], [k for k in range(40) if k != 7])
