"""Pareto fronts (:mod:`evaluators.metrics.pareto`) against a brute-force dominance check,
on random points with many ties, and the spread of repeated values."""

from __future__ import annotations

import statistics

import numpy as np
import pytest

from evaluators.metrics.pareto import dominated_by, dominates, front_indices, spread


def brute_front(costs: list[float], errors: list[float]) -> set[int]:
    """Indices no other point beats on both coordinates (one strictly): the definition."""
    pts = list(zip(costs, errors, strict=True))
    return {
        i
        for i, (c, e) in enumerate(pts)
        if not any(
            c2 <= c and e2 <= e and (c2 < c or e2 < e) for j, (c2, e2) in enumerate(pts) if j != i
        )
    }


@pytest.mark.parametrize("seed", range(40))
def test01_front_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 30))
    # few distinct values: many ties in cost, in error and in both
    costs = [float(v) for v in rng.integers(0, 6, n)]
    errors = [float(v) for v in rng.integers(0, 6, n)]
    got = front_indices(costs, errors)
    assert set(got) == brute_front(costs, errors)
    assert len(got) == len(set(got))
    assert [costs[i] for i in got] == sorted(costs[i] for i in got)  # ordered by cost
    beaten = dominated_by(costs, errors)
    for i in range(n):
        assert (beaten[i] == []) == (i in set(got))
        assert all(dominates((costs[j], errors[j]), (costs[i], errors[i])) for j in beaten[i])


def test02_known_front() -> None:
    costs = [2.0, 50.0, 60.0, 200.0, 200.0, 1.0]
    errors = [0.20, 0.10, 0.15, 0.05, 0.05, 0.30]
    # 60/0.15 is beaten by 50/0.10; the two equal points at 200 do not beat each other
    assert front_indices(costs, errors) == [5, 0, 1, 3, 4]
    assert dominated_by(costs, errors)[2] == [1]


def test03_errors() -> None:
    with pytest.raises(ValueError, match="length"):
        front_indices([1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        front_indices([1.0, float("nan")], [1.0, 2.0])
    with pytest.raises(ValueError, match="no values"):
        spread([])
    assert front_indices([], []) == []


def test04_spread() -> None:
    vals = [0.28, 0.30, 0.61]
    s = spread(vals)
    assert s["n"] == 3 and s["min"] == 0.28 and s["max"] == 0.61
    assert s["mean"] == pytest.approx(np.mean(vals))
    assert s["std"] == pytest.approx(np.std(vals, ddof=1))
    assert spread([0.5]) == {"n": 1, "mean": 0.5, "std": 0.0, "min": 0.5, "max": 0.5}
    assert statistics.fmean(vals) == s["mean"]
