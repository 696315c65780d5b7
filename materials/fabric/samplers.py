"""Sample points for the footprint estimator: independent, or scrambled Sobol.

Each query gets ``samples`` points in ``(0, 1)^3`` (dimensions: footprint position u1, u2;
visibility-march jitter), laid out as ``replicates`` consecutive blocks of
``block = samples / replicates`` points. Points depend only on ``(seed, query index)``, never
on how a caller chunks its queries, so the numpy and Dr.Jit estimators see identical points.

- ``"independent"``: uniform float32 draws from numpy's PCG64, one stream per block of
  :data:`QUERY_BLOCK` queries seeded with ``(seed, block index)``.
- ``"sobol"``: randomised QMC. ``replicates`` independent scrambles of the first
  ``block`` Sobol points (``scipy.stats.qmc.Sobol(scramble=True)``, i.e. Matousek's linear
  matrix scrambling plus a digital shift, seeded from ``seed``; ``block`` must be a power of
  two so each is a (t, m, 3)-net), shared by all queries, and on top of each a per-query
  random *digital shift* (XOR of the 32-bit coordinates), which keeps the net property and
  makes every query's replicates independent, unbiased randomisations. The spread of the
  replicate means gives the standard error (``aggregate.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Literal

import numpy as np
from scipy.stats import qmc

Sampler = Literal["independent", "sobol"]
SAMPLERS: tuple[str, ...] = ("independent", "sobol")

#: Coordinates per sample: footprint position (2) and the visibility-march jitter (1).
DIMENSIONS = 3
#: Queries per random stream; chunk queries in multiples of this to avoid regenerating.
QUERY_BLOCK = 64

_TAG_INDEPENDENT = 0x1D
_TAG_SHIFT = 0x5F
_TAG_SCRAMBLE = 0x5C


def check_sampling(sampler: str, samples: int, replicates: int) -> None:
    """Raise ``ValueError`` unless the sampler, sample count and replicate count fit."""
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}, got {sampler!r}")
    if replicates < 2:
        raise ValueError(f"replicates must be >= 2, got {replicates}")
    if samples < replicates or samples % replicates:
        raise ValueError(
            f"samples ({samples}) must be a positive multiple of replicates ({replicates})"
        )
    block = samples // replicates
    if sampler == "sobol" and block & (block - 1):
        raise ValueError(
            f"sobol needs samples / replicates to be a power of two, got {samples} / {replicates}"
        )


@lru_cache(maxsize=16)
def scrambled_nets(seed: int, replicates: int, block: int) -> np.ndarray:
    """``(replicates, block, DIMENSIONS)`` uint32: independently scrambled Sobol nets.

    ``block`` must be a power of two. Cached; the array is read-only.
    """
    if block < 1 or block & (block - 1):
        raise ValueError(f"block must be a power of two, got {block}")
    m = block.bit_length() - 1
    nets = np.empty((replicates, block, DIMENSIONS), dtype=np.uint32)
    for r in range(replicates):
        rng = np.random.default_rng([seed, _TAG_SCRAMBLE, r])
        pts = qmc.Sobol(d=DIMENSIONS, scramble=True, bits=32, rng=rng).random_base2(m)
        # The floats are exact multiples of 2^-32: recover the integers losslessly.
        nets[r] = np.floor(pts * 2.0**32).astype(np.uint32)
    nets.setflags(write=False)
    return nets


def _per_block(
    first_query: int,
    n_queries: int,
    seed: int,
    tag: int,
    draw: Callable[[np.random.Generator, int], np.ndarray],
) -> np.ndarray:
    """Concatenate ``draw(rng, rows)`` over the query blocks covering the requested range.

    Each block of :data:`QUERY_BLOCK` queries has its own stream seeded with
    ``(seed, tag, block index)``; streams are sequential, so drawing the first ``hi`` rows
    and dropping ``lo`` keeps every query's rows the same however callers chunk.
    """
    if first_query < 0 or n_queries < 0:
        raise ValueError("query indices must be non-negative")
    parts = []
    q, end = first_query, first_query + n_queries
    while q < end:
        b = q // QUERY_BLOCK
        lo = q - b * QUERY_BLOCK
        hi = min(end - b * QUERY_BLOCK, QUERY_BLOCK)
        parts.append(draw(np.random.default_rng([seed, tag, b]), hi)[lo:])
        q = b * QUERY_BLOCK + hi
    if not parts:
        return draw(np.random.default_rng(0), 0)
    return np.concatenate(parts)


def digital_shifts(seed: int, first_query: int, n_queries: int, replicates: int) -> np.ndarray:
    """``(n_queries, replicates, DIMENSIONS)`` uint32 random digital shifts (XOR masks)."""
    return _per_block(
        first_query,
        n_queries,
        seed,
        _TAG_SHIFT,
        lambda rng, rows: rng.integers(
            0, 2**32, size=(rows, replicates, DIMENSIONS), dtype=np.uint32
        ),
    )


def bits_to_unit(bits: np.ndarray) -> np.ndarray:
    """uint32 -> float32 in (0, 1): the top 24 bits, centred in their cell (never 0 or 1)."""
    return ((bits >> np.uint32(8)).astype(np.float32) + np.float32(0.5)) * np.float32(2.0**-24)


def sample_points(
    sampler: Sampler,
    *,
    seed: int,
    first_query: int,
    n_queries: int,
    samples: int,
    replicates: int,
) -> np.ndarray:
    """Points of queries ``first_query .. first_query + n_queries - 1``.

    Returns ``(n_queries, samples, DIMENSIONS)`` float32 in ``(0, 1)``; sample ``k`` belongs
    to replicate ``k // (samples / replicates)``. For ``"sobol"``, point ``i`` of replicate
    ``r`` of query ``q`` is ``bits_to_unit(nets[r, i] ^ shifts[q, r])``.
    """
    check_sampling(sampler, samples, replicates)
    if sampler == "independent":
        return _per_block(
            first_query,
            n_queries,
            seed,
            _TAG_INDEPENDENT,
            lambda rng, rows: rng.random((rows, samples, DIMENSIONS), dtype=np.float32),
        )
    block = samples // replicates
    nets = scrambled_nets(seed, replicates, block)
    shifts = digital_shifts(seed, first_query, n_queries, replicates)
    out = np.empty((n_queries, replicates, block, DIMENSIONS), dtype=np.float32)
    for q in range(0, n_queries, QUERY_BLOCK):  # cache-sized pieces
        sl = slice(q, q + QUERY_BLOCK)
        out[sl] = bits_to_unit(nets[None, :, :, :] ^ shifts[sl, :, None, :])
    return out.reshape(n_queries, samples, DIMENSIONS)
