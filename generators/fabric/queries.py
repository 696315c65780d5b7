"""The stratified query design of ``generate.fabric`` (Chen et al. 2024, Sec. 5.1).

A query is a footprint (centre, size) and a direction pair (``wi`` light, ``wo`` view) at
which :func:`materials.fabric.aggregate.estimate` evaluates the four components. Sec. 5.1:

- **Centres**: the tile (``[0, 1)^2``, tile units, ``L_t = 1``) is cut into 8 x 8 cells and
  one centre is drawn uniformly in a cell.
- **Sizes**: 20 strata, 10 equal ones over ``[0, L_t]`` (width 0.1) and 10 over
  ``[L_t, 5 L_t]`` (width 0.4); one size is drawn uniformly in a stratum. Sizes are box
  footprint sides in tile units.
- **Log-uniform sizes** (``sizes="log_uniform"``, issue 12): the same 20 strata, equal in
  ``ln size`` over ``[LOG_SIZE_MIN, 5]`` tiles, sizes log-uniform within each. Renders'
  pixel footprints (``cloth_plane``: 0.03-0.1 tile) sit in the paper design's least
  populated stratum (``[0, 0.1]``, 1/20 of the queries); here about a fifth of the queries
  fall in 0.03-0.1 tile, and the rest still span up to 5 tiles for distant views.
- **Directions**: "stratified sampling the x and y components of both directions in a 8x8
  grid and computing the z component". A direction's stratum is a cell ``(ix, iy)`` of an
  8 x 8 grid over the unit square; a jittered point ``(u, v)`` in it is mapped to the unit
  disk by Shirley & Chiu's concentric map (equal-area, so strata keep equal area and stay
  compact) and lifted to ``z = sqrt(1 - x^2 - y^2)``. The result is cosine-distributed over
  the hemisphere: the same distribution as the paper's uniform ``x, y`` in ``[-1, 1]^2``
  with the points outside the disk rejected -- its "around 2500 valid pairs" is
  ``64^2 (pi / 4)^2 = 2527`` -- but with no rejection, so every one of the ``64 x 64 = 4096``
  pair cells is valid and the query count is exact. ``z`` is clamped to at least
  :data:`MIN_Z` (then renormalised), since the estimator needs ``wo_z > 0`` and ``wi_z != 0``.
- **BRDF and BTDF pairs**: ``wo`` is always above (``z > 0``). A BRDF pair has ``wi`` above
  too; a BTDF pair has ``wi`` below, ``wi = (x, y, -z)`` (light from under the cloth,
  ``integrand.py``). A fraction ``btdf_fraction`` of the pair cells in every round
  (default :data:`BTDF_FRACTION` = 1/2, ``round(4096 f)`` cells) are BTDF pairs, drawn
  without replacement, so both kinds cover the whole stratum grid.

Budget (:func:`design_queries`). The full factorial design, 64 centres x 20 sizes x 4096
pairs = 5.2 M queries, is more than wanted (the paper keeps about 3.2 M per material, and
small runs a few hundred), so each factor is stratified on its own, Latin-hypercube style:
query ``k`` takes, for a factor of ``m`` cells, the cell ``perm_r[k mod m]`` of round
``r = k // m``, where ``perm_r`` is a random permutation of the ``m`` cells with its own
jitters, seeded by ``(seed, factor, r)``. Every complete round visits each cell exactly
once; a partial round visits distinct cells. Because each round is generated from its own
seed, any range of queries can be generated alone, and a shard's queries do not depend on
how the material is split into shards. A query count that is a multiple of 20480
(``lcm(64, 20, 4096)``) completes every factor's rounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Centre strata per tile side (8 x 8 cells).
CENTRE_GRID = 8
#: Size strata: ``(low, high, count)`` in tile sizes ``L_t`` (Sec. 5.1: 10 + 10).
SIZE_STRATA: tuple[tuple[float, float, int], ...] = ((0.0, 1.0, 10), (1.0, 5.0, 10))
#: Smallest footprint of the log-uniform size design, tile units.
LOG_SIZE_MIN = 0.01
#: Size designs: the paper's strata, or log-uniform strata.
SIZE_DESIGNS: tuple[str, ...] = ("strata", "log_uniform")
#: Direction strata per side of the unit square, per direction (8 x 8 for wi and for wo).
DIRECTION_GRID = 8
#: Default fraction of direction pairs with the light below (BTDF pairs).
BTDF_FRACTION = 0.5
#: Smallest ``|z|`` of a direction (keeps ``wo_z > 0`` and ``wi_z != 0`` at the disk's rim).
MIN_Z = 1e-4

_TAG_CENTRE, _TAG_SIZE, _TAG_PAIR = 0xC3, 0x51, 0xD1


@dataclass(frozen=True)
class QueryBatch:
    """``N`` queries, float64; footprints in tile units, directions in the macro frame."""

    centre: np.ndarray
    """``(N, 2)`` footprint centres ``(s, t)`` in ``[0, 1)``."""
    size: np.ndarray
    """``(N,)`` footprint sizes in ``[0, 5]`` tile sizes."""
    wi: np.ndarray
    """``(N, 3)`` unit light directions; ``wi_z < 0`` for BTDF pairs."""
    wo: np.ndarray
    """``(N, 3)`` unit view directions, ``wo_z > 0``."""

    def __len__(self) -> int:
        return int(self.size.shape[0])


def size_edges(sizes: str = "strata") -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper edges of the 20 size strata, ``(20,)`` each, tile units (for
    ``"log_uniform"``, equal in ``ln size`` from :data:`LOG_SIZE_MIN` to 5)."""
    if sizes == "log_uniform":
        n = sum(c for _, _, c in SIZE_STRATA)
        e = np.exp(np.linspace(np.log(LOG_SIZE_MIN), np.log(SIZE_STRATA[-1][1]), n + 1))
        return e[:-1], e[1:]
    if sizes != "strata":
        raise ValueError(f"sizes must be one of {SIZE_DESIGNS}, got {sizes!r}")
    lo, hi = [], []
    for a, b, n in SIZE_STRATA:
        e = np.linspace(a, b, n + 1)
        lo.append(e[:-1])
        hi.append(e[1:])
    return np.concatenate(lo), np.concatenate(hi)


def concentric_disk(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley & Chiu's concentric map of ``[0, 1]^2`` onto the unit disk (equal-area)."""
    a = 2.0 * np.asarray(u, dtype=np.float64) - 1.0
    b = 2.0 * np.asarray(v, dtype=np.float64) - 1.0
    first = np.abs(a) > np.abs(b)
    safe_a = np.where(a == 0, 1.0, a)
    safe_b = np.where(b == 0, 1.0, b)
    r = np.where(first, a, b)
    phi = np.where(first, (np.pi / 4) * (b / safe_a), np.pi / 2 - (np.pi / 4) * (a / safe_b))
    r = np.where((a == 0) & (b == 0), 0.0, r)
    return r * np.cos(phi), r * np.sin(phi)


def stratum_directions(cell: np.ndarray, jitter: np.ndarray) -> np.ndarray:
    """``(N, 3)`` upper-hemisphere directions from 8 x 8 strata.

    ``cell`` is ``(N,)`` ints in ``[0, 64)``, ``ix = cell % 8``, ``iy = cell // 8``;
    ``jitter`` is ``(N, 2)`` in ``[0, 1)``. The point ``((ix + jx) / 8, (iy + jy) / 8)`` goes
    through :func:`concentric_disk`, then ``z = max(sqrt(1 - x^2 - y^2), MIN_Z)``.
    """
    cell = np.asarray(cell)
    n = DIRECTION_GRID
    u = (cell % n + jitter[:, 0]) / n
    v = (cell // n + jitter[:, 1]) / n
    x, y = concentric_disk(u, v)
    z = np.maximum(np.sqrt(np.maximum(1.0 - x * x - y * y, 0.0)), MIN_Z)
    d = np.stack([x, y, z], axis=1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _round_rng(seed: int, tag: int, r: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, tag, r]))


def factor_cells(
    seed: int, tag: int, m: int, dims: int, first: int, count: int, extra: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells ``(count,)`` and jitters ``(count, dims)`` of one factor for queries
    ``first .. first + count - 1`` (round by round; see the module docstring)."""
    cells = np.empty(count, dtype=np.int64)
    jitter = np.empty((count, dims))
    flags = np.zeros(count, dtype=bool)
    k = first
    end = first + count
    while k < end:
        r, pos = divmod(k, m)
        take = min(m - pos, end - k)
        rng = _round_rng(seed, tag, r)
        perm = rng.permutation(m)
        jit = rng.random((m, dims))
        out = slice(k - first, k - first + take)
        cells[out] = perm[pos : pos + take]
        jitter[out] = jit[pos : pos + take]
        if extra is not None:  # BTDF flags: a fixed count of the round's cells, at random
            below = rng.permutation(m) < extra
            flags[out] = below[pos : pos + take]
        k += take
    return cells, jitter, flags


def design_centres(seed: int, first: int, count: int) -> np.ndarray:
    """``(count, 2)`` footprint centres of queries ``first .. first + count - 1``: one
    jittered point in a cell of the 8 x 8 grid over the tile, cells stratified by rounds."""
    g = CENTRE_GRID
    cells, jit, _ = factor_cells(seed, _TAG_CENTRE, g * g, 2, first, count)
    return np.stack([(cells % g + jit[:, 0]) / g, (cells // g + jit[:, 1]) / g], axis=1)


def design_queries(
    seed: int,
    first: int,
    count: int,
    *,
    btdf_fraction: float = BTDF_FRACTION,
    sizes: str = "strata",
) -> QueryBatch:
    """Queries ``first .. first + count - 1`` of one material's stratified design.

    Parameters
    ----------
    seed
        The material's design seed (any non-negative int).
    first, count
        The query range; the result does not depend on how a material's range is split.
    btdf_fraction
        Fraction of each round's 4096 direction-pair cells with the light below.
    sizes
        ``"strata"`` (Sec. 5.1) or ``"log_uniform"`` (see the module docstring).

    Returns
    -------
    :class:`QueryBatch` of ``count`` queries.
    """
    if first < 0 or count < 0:
        raise ValueError(f"first and count must be >= 0, got {first}, {count}")
    if not 0.0 <= btdf_fraction <= 1.0:
        raise ValueError(f"btdf_fraction must be in [0, 1], got {btdf_fraction}")
    centre = design_centres(seed, first, count)
    lo, hi = size_edges(sizes)
    cells, jit, _ = factor_cells(seed, _TAG_SIZE, len(lo), 1, first, count)
    if sizes == "log_uniform":
        size = lo[cells] * (hi[cells] / lo[cells]) ** jit[:, 0]
    else:
        size = lo[cells] + (hi[cells] - lo[cells]) * jit[:, 0]
    m = (DIRECTION_GRID**2) ** 2
    n_below = round(m * btdf_fraction)
    cells, jit, below = factor_cells(seed, _TAG_PAIR, m, 4, first, count, extra=n_below)
    d = DIRECTION_GRID**2
    wi = stratum_directions(cells // d, jit[:, 0:2])
    wo = stratum_directions(cells % d, jit[:, 2:4])
    wi[below, 2] *= -1.0
    return QueryBatch(centre=centre, size=size, wi=wi, wo=wo)
