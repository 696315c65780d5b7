"""Pareto fronts of error against cost, and the spread of repeated measurements.

Pure functions over plain numbers: no I/O, no job code. Both coordinates are lower-is-better
(an error and a cost). A point *dominates* another when it is no worse on both and strictly
better on at least one; the *front* is the set of points no other point dominates. Equal
points do not dominate each other, so ties are all on the front.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence


def _check(costs: Sequence[float], errors: Sequence[float]) -> None:
    if len(costs) != len(errors):
        raise ValueError(f"costs and errors differ in length: {len(costs)} != {len(errors)}")
    bad = [i for i, v in enumerate([*costs, *errors]) if not math.isfinite(v)]
    if bad:
        raise ValueError("costs and errors must be finite numbers")


def dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether ``a = (cost, error)`` dominates ``b`` (no worse on both, better on one)."""
    return a[0] <= b[0] and a[1] <= b[1] and (a[0] < b[0] or a[1] < b[1])


def front_indices(costs: Sequence[float], errors: Sequence[float]) -> list[int]:
    """Indices of the non-dominated points, ordered by cost then error then index.

    O(n log n): sweep the points by increasing cost; at each cost only the points of least
    error there can be on the front, and only if that error is below every cheaper point's.
    Raises ``ValueError`` for sequences of different lengths or non-finite values.
    """
    _check(costs, errors)
    order = sorted(range(len(costs)), key=lambda i: (costs[i], errors[i], i))
    front: list[int] = []
    best = math.inf  # least error among strictly cheaper points
    k = 0
    while k < len(order):
        cost = costs[order[k]]
        group = []
        while k < len(order) and costs[order[k]] == cost:
            group.append(order[k])
            k += 1
        least = errors[group[0]]  # the group is sorted by error
        if least < best:
            front.extend(i for i in group if errors[i] == least)
            best = least
    return front


def dominated_by(costs: Sequence[float], errors: Sequence[float]) -> list[list[int]]:
    """For each point, the indices of the points that dominate it (empty on the front)."""
    _check(costs, errors)
    pts = list(zip(costs, errors, strict=True))
    return [[j for j, q in enumerate(pts) if j != i and dominates(q, p)] for i, p in enumerate(pts)]


def spread(values: Sequence[float]) -> dict[str, float | int]:
    """``{"n", "mean", "std", "min", "max"}`` of repeated measurements (e.g. over seeds);
    ``std`` is the sample standard deviation (``ddof = 1``), 0 for one value."""
    if not values:
        raise ValueError("no values")
    return {
        "n": len(values),
        "mean": statistics.fmean(values),
        "std": statistics.stdev(values) if len(values) > 1 else 0.0,
        "min": min(values),
        "max": max(values),
    }


#: A point with its spread: ``(cost_lo, cost_hi, error_lo, error_hi)``.
Box = tuple[float, float, float, float]


def surely_dominates(a: Box, b: Box) -> bool:
    """Whether ``a`` dominates ``b`` wherever in their spreads the two points lie: ``a``'s
    worst is no worse than ``b``'s best on both axes, and better on one."""
    return a[1] <= b[0] and a[3] <= b[2] and (a[1] < b[0] or a[3] < b[2])


def possibly_dominates(a: Box, b: Box) -> bool:
    """Whether some values inside the spreads let ``a`` beat or equal ``b`` on both axes:
    ``a``'s best is no worse than ``b``'s worst on each (equal points count: a tie)."""
    return a[0] <= b[1] and a[2] <= b[3]


def unresolved_with(boxes: Sequence[Box], front: Sequence[int]) -> list[list[int]]:
    """Per point, the points that make its place undecided within the spreads (empty:
    decided). A point on the ``front`` (by its central values) is undecided when another
    point :func:`possibly_dominates` it; a point off the front when no other point
    :func:`surely_dominates` it, and then its ties are the points that possibly dominate it.
    With no spread (degenerate boxes) only equal points tie."""
    on = set(front)
    out: list[list[int]] = []
    for i, b in enumerate(boxes):
        maybe = [j for j in range(len(boxes)) if j != i and possibly_dominates(boxes[j], b)]
        if i not in on and any(surely_dominates(boxes[j], b) for j in maybe):
            maybe = []
        out.append(maybe)
    return out
