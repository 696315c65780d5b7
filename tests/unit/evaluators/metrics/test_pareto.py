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


# -- decisions inside the spread ----------------------------------------------------------


def test_sure_and_possible_dominance_on_boxes() -> None:
    from evaluators.metrics.pareto import possibly_dominates, surely_dominates

    a, b = (1.0, 2.0, 0.1, 0.2), (3.0, 4.0, 0.3, 0.4)  # a below and left of b, apart
    assert surely_dominates(a, b) and possibly_dominates(a, b)
    assert not surely_dominates(b, a) and not possibly_dominates(b, a)
    c = (1.5, 3.5, 0.15, 0.35)  # overlaps both
    assert not surely_dominates(a, c) and possibly_dominates(a, c) and possibly_dominates(c, a)
    point = (2.0, 2.0, 0.2, 0.2)  # no spread: dominance as for points
    assert surely_dominates(point, (2.0, 2.0, 0.3, 0.3))
    assert not surely_dominates(point, point) and possibly_dominates(point, point)


def test_unresolved_with_names_the_ties() -> None:
    from evaluators.metrics.pareto import unresolved_with

    # 0 and 1: both on the front by their centres, boxes overlap on both axes -> tied;
    # 2: dominated by 0 surely -> resolved; 3: dominated by 0 and 1 by centres only -> tied
    # with both (and its best corner, 12.5 ns at 0.12, could beat 1's worst: 1 ties with it)
    boxes = [
        (10.0, 12.0, 0.10, 0.14),
        (11.0, 13.0, 0.09, 0.13),
        (20.0, 21.0, 0.30, 0.31),
        (12.5, 14.0, 0.12, 0.15),
    ]
    ties = unresolved_with(boxes, front=[0, 1])
    assert ties[0] == [1] and ties[1] == [0, 3]
    assert ties[2] == []
    assert ties[3] == [0, 1]
    # the same points without spread: the front is decided, nothing ties
    flat = [(b[0], b[0], b[2], b[2]) for b in boxes]
    assert unresolved_with(flat, front=front_indices([b[0] for b in flat],
                                                     [b[2] for b in flat])) == [[]] * 4  # fmt: skip
    # two identical points are a tie even without spread
    assert unresolved_with([(1.0, 1.0, 0.1, 0.1)] * 2, front=[0, 1]) == [[1], [0]]
