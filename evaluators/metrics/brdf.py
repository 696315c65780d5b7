"""BRDF-space error metrics: SMAPE (Eq. 6 of the hybrid-BRDF paper), a floored SMAPE
(:func:`smape_floor`, stable where the table is exactly 0) and MAE.

The paper: De Oliveira, Karpova, Nader, Houdard, Mezieres, Rioux-Lavoie and Pacanowski,
"A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering" (Sec. 4.1, Eq. 6).

Pure functions in the manner of ``skimage.metrics`` and :mod:`evaluators.metrics.images`: arrays in,
numbers out; shapes are checked first, dtypes promoted once to float64, options are
keyword-only, and every refusal is an explicit ``ValueError``.

What is compared
----------------
Both metrics compare **plain BRDF values** ``f(wi, wo)`` in 1/sr, RGB, with no cosine
factor: the paper's Eq. 6 is written on ``f``, not on the ``cos(theta_i) f`` of its training
loss (Eq. 5). For SMAPE the choice does not matter: each term is invariant under a positive
common factor, so ``f`` and ``cos(theta_i) f`` give the same value. It matters for MAE, which
is in 1/sr.

Where they are compared
-----------------------
The paper (Sec. 4.1) samples "both the target and the estimated BRDF with 10^6 directions"
and does not state the distribution; for fitting (Sec. 3.3) it draws pairs "from a
cosine-weighted distribution over the hemisphere". :func:`direction_pairs` follows that: by
default ``wi`` and ``wo`` are independent, each cosine-weighted on the upper hemisphere
(pdf ``cos(theta) / pi``), ``10**6`` pairs from the fixed seed :data:`PAIRS_SEED`, so every
score uses the same pairs.

Anything with ``eval(wi, wo) -> (N, 3)`` plain BRDF values is a :class:`BrdfSampler`; MERL
tables are wrapped by :class:`TableSampler` (multilinear lookup, see its docstring), fitted
models will be samplers of their own.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from materials import halfdiff as hd
from storage.formats.merl import MerlTable

#: Number of direction pairs of a BRDF-space score (Sec. 4.1 of the hybrid-BRDF paper).
DEFAULT_PAIRS = 1_000_000
#: The fixed seed of the scoring pairs: every score draws the very same pairs.
PAIRS_SEED = 20_250_601
#: Rows per ``eval`` call in :func:`sample_brdf` (bounded memory; also faster: cache-sized).
SAMPLE_CHUNK = 1 << 16

Distribution = Literal["cosine", "uniform"]
#: Human-readable descriptions of each distribution, as written into ``metrics.json``.
DISTRIBUTIONS: dict[str, str] = {
    "cosine": "wi and wo independent, each cosine-weighted on the upper hemisphere "
    "(pdf cos(theta)/pi): z = sqrt(1 - u1), phi = 2 pi u2",
    "uniform": "wi and wo independent, each uniform on the upper hemisphere "
    "(pdf 1/(2 pi)): z = 1 - u1, phi = 2 pi u2",
}


# -- direction pairs -------------------------------------------------------------------------


def direction_pairs(
    n: int = DEFAULT_PAIRS, *, seed: int = PAIRS_SEED, distribution: Distribution = "cosine"
) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``n`` direction pairs on the upper hemisphere, deterministically.

    Parameters
    ----------
    n
        Number of pairs (the paper uses ``10**6``, Sec. 4.1).
    seed
        Seed of ``numpy.random.default_rng``; default :data:`PAIRS_SEED`.
    distribution
        ``"cosine"`` (default): ``wi`` and ``wo`` independent, each with pdf
        ``cos(theta) / pi`` (the paper's fitting distribution, Sec. 3.3), drawn by Malley's
        method ``z = sqrt(1 - u1)``, ``r = sqrt(u1)``, ``phi = 2 pi u2``; then
        ``E[cos theta] = 2/3``. ``"uniform"``: each with pdf ``1 / (2 pi)``, ``z = 1 - u1``;
        ``E[cos theta] = 1/2``.

    Returns
    -------
    wi, wo
        ``(n, 3)`` float64 unit vectors in the local frame, z up, with ``z > 0``. The
        uniforms are one ``(4, n)`` draw: rows 0-1 make ``wi``, rows 2-3 make ``wo``.
    """
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    if distribution not in DISTRIBUTIONS:
        raise ValueError(
            f"unknown distribution {distribution!r}; use one of {', '.join(DISTRIBUTIONS)}"
        )
    u = np.random.default_rng(seed).random((4, int(n)))  # in [0, 1), so z > 0 below

    def hemisphere(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
        z = np.sqrt(1.0 - u1) if distribution == "cosine" else 1.0 - u1
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        phi = (2.0 * math.pi) * u2
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)

    return hemisphere(u[0], u[1]), hemisphere(u[2], u[3])


# -- samplers --------------------------------------------------------------------------------


@runtime_checkable
class BrdfSampler(Protocol):
    """Anything that evaluates a BRDF at direction pairs: a table, later a fitted model.

    ``eval(wi, wo)`` takes ``(N, 3)`` unit directions in the local frame (z up) and returns
    ``(N, 3)`` plain RGB BRDF values in 1/sr (no cosine factor); negative values mean "no
    data here".
    """

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class TableSampler:
    """A MERL table as a :class:`BrdfSampler`, through :func:`materials.halfdiff.lookup`.

    ``interpolate=True`` (default, and what ``score`` uses for reference and candidates
    alike): multilinear interpolation between bin centres in the MERL coordinates. The
    tables hold one sample per bin at its centre, so this is the continuous reconstruction
    of the tabulated function; nearest-bin lookup would add a staircase error of the
    1-degree / square-root bins to every comparison with a smooth model. Pairs whose
    neighbouring bins are all missing give -1.
    """

    table: MerlTable
    interpolate: bool = True

    def eval(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``(N, 3)`` BRDF values in 1/sr at ``(N, 3)`` pairs; -1 where there is no data."""
        return hd.lookup(self.table.rgb, wi, wo, interpolate=self.interpolate)


def sample_brdf(
    sampler: BrdfSampler,
    wi: np.ndarray,
    wo: np.ndarray,
    *,
    chunk: int = SAMPLE_CHUNK,
    workers: int = 1,
) -> np.ndarray:
    """Evaluate ``sampler`` at ``(N, 3)`` pairs in chunks of ``chunk`` rows.

    ``workers > 1`` evaluates chunks on that many threads (numpy releases the GIL in its
    array loops; a table lookup runs about twice as fast on two free cores). Only for
    thread-safe samplers such as :class:`TableSampler`; the result does not depend on it.

    Returns ``(N, 3)`` float64. Raises ``ValueError`` if the sampler returns another shape
    or non-finite values.
    """
    wi, wo = np.asarray(wi), np.asarray(wo)
    if wi.ndim != 2 or wi.shape[1] != 3 or wi.shape != wo.shape:
        raise ValueError(f"wi and wo must both have shape (N, 3), got {wi.shape} and {wo.shape}")
    if chunk < 1 or workers < 1:
        raise ValueError(f"chunk and workers must be positive, got {chunk} and {workers}")
    out = np.empty((len(wi), 3))
    starts = range(0, len(wi), chunk)

    def fill(start: int) -> None:
        rows = slice(start, start + chunk)
        part = np.asarray(sampler.eval(wi[rows], wo[rows]))
        expected = (len(wi[rows]), 3)
        if part.shape != expected:
            raise ValueError(f"the BRDF returned shape {part.shape} for {expected[0]} pairs")
        out[rows] = part

    if workers == 1 or len(starts) == 1:
        for start in starts:
            fill(start)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(fill, starts))  # list(): re-raise the first error here
    bad = int(np.count_nonzero(~np.isfinite(out)))
    if bad:
        raise ValueError(f"the BRDF returned {bad} non-finite values (NaN or infinity)")
    return out


# -- metrics ---------------------------------------------------------------------------------


def _check_values(
    ref: np.ndarray, test: np.ndarray, weights: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Validate BRDF values and weights; return float64 arrays (weights shaped to broadcast)."""
    a, b = np.asarray(ref), np.asarray(test)
    if a.shape != b.shape:
        raise ValueError(f"BRDF values differ in shape: reference {a.shape}, test {b.shape}")
    if a.ndim not in (1, 2) or a.size == 0:
        raise ValueError(f"BRDF values must be non-empty (N,) or (N, C) arrays, got {a.shape}")
    for label, arr in (("reference", a), ("test", b)):
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"{label} values must be numeric, got dtype {arr.dtype}")
    a, b = a.astype(np.float64, copy=False), b.astype(np.float64, copy=False)
    for label, arr in (("reference", a), ("test", b)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        if bad:
            raise ValueError(f"{label} has {bad} non-finite values (NaN or infinity)")
    if weights is None:
        return a, b, None
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != a.shape[:1]:
        raise ValueError(f"weights must have shape {a.shape[:1]} (one per pair), got {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    if not w.sum() > 0:
        raise ValueError("weights sum to zero")
    return a, b, w.reshape(w.shape + (1,) * (a.ndim - 1))


def _mean(terms: np.ndarray, w: np.ndarray | None) -> float:
    """Mean of ``terms`` over pairs and channels, pairs weighted by ``w``."""
    if w is None:
        return float(np.mean(terms))
    per_pair = terms if terms.ndim == 1 else terms.mean(axis=1)
    return float(np.sum(w.reshape(-1) * per_pair) / np.sum(w))


def smape(
    ref: np.ndarray, test: np.ndarray, *, weights: np.ndarray | None = None, eps: float = 0.0
) -> float:
    """Symmetric mean absolute percentage error, Eq. 6 of De Oliveira et al., "A Hybrid
    Neural-Microfacet BRDF Model for Real-Time Rendering" (Sec. 4.1)::

        SMAPE(f, f^) = 2/N * sum_k |f_k - f^_k| / (|f_k| + |f^_k|)

    over the ``N`` direction pairs ``k``. For ``(N, C)`` values each channel is a term of
    its own and the sum is normalised by ``N * C``: the mean of the per-channel SMAPEs.

    Parameters
    ----------
    ref, test
        ``(N,)`` or ``(N, C)`` BRDF values of the same shape, typically ``(N, 3)`` plain RGB
        values in 1/sr at the same pairs (see the module docstring for why ``f`` and not
        ``cos(theta_i) f``). Absolute values enter, as in Eq. 6; callers drop missing
        (negative) entries first.
    weights
        Optional ``(N,)`` non-negative weights per pair: ``2 sum w_k t_k / sum w_k`` instead
        of the plain mean (e.g. to importance-weight pairs drawn from another distribution).
    eps
        Added to the denominator, ``|f - f^| / (|f| + |f^| + eps)``: a floor below which
        values count as equal. Default 0, Eq. 6 exactly.

    Returns
    -------
    float
        In ``[0, 2]``: 0 when ``ref == test``; 2 when every pair has values of opposite sign
        or one zero and the other not. A term ``0 / 0`` (both values 0) is defined as 0,
        perfect agreement. SMAPE is symmetric in ``ref`` and ``test`` and invariant under a
        common positive scale of both, but not under scaling one of them.

    Raises
    ------
    ValueError
        Shapes differ or are not (N,) / (N, C), values are non-finite, weights are
        ill-shaped, negative or all zero, or ``eps`` is negative or non-finite.
    """
    if not (math.isfinite(eps) and eps >= 0.0):
        raise ValueError(f"eps must be a finite non-negative number, got {eps!r}")
    a, b, w = _check_values(ref, test, weights)
    num = np.abs(a - b)
    den = np.abs(a) + np.abs(b) + eps
    # 0/0 (both values zero) counts as agreement; num <= den, so each term is in [0, 1].
    terms = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    return 2.0 * _mean(terms, w)


#: :func:`smape_floor`'s default floor, as a fraction of the reference's mean per channel.
SMAPE_FLOOR_FRACTION = 0.01


def smape_floor(
    ref: np.ndarray,
    test: np.ndarray,
    *,
    weights: np.ndarray | None = None,
    fraction: float = SMAPE_FLOOR_FRACTION,
) -> float:
    """SMAPE with each channel's denominator floored at ``fraction`` of the reference's mean::

        SMAPE_floor = 2/N * sum_k |f_k - f^_k| / max(|f_k| + |f^_k|, delta_c),
        delta_c = fraction * mean_k |f_k,c|   (weighted by ``weights`` if given)

    Why: Eq. 6 (:func:`smape`, eps 0) scores 2, its maximum, at every pair where the table is
    exactly 0 and the model is not, however small the model's value. Measured MERL data (the
    paper's) has no exact zeros, but synthetic near-specular tables (Beckmann alpha 0.02) are
    0 at almost every pair, so any smooth model's tail scores about 2 there and the material's
    SMAPE says nothing about the fit. This instability of SMAPE near zero is the classic
    objection to it (Hyndman and Koehler, "Another look at measures of forecast accuracy",
    Int. J. Forecasting 22(4), 2006); the usual cure, flooring the denominator at a scale
    of the data, is the one here (as the small constant in the denominator of the relative
    MSE that scores renderings). The floor is *relative* to the table's own
    mean so that, like Eq. 6, the variant is invariant under a common positive scale of both
    BRDFs, and *a max, not a sum*, so that it equals Eq. 6 exactly at every pair where
    ``|f| + |f^| >= delta``: on tables without values below about 1 % of their mean the two
    agree. A pair where ``|f| + |f^|`` is below the floor scores ``|f - f^| / delta``
    (below 1), its absolute error in units of ``delta``: a table 0 and a model tail of
    ``0.001 x`` the table's mean score ``0.1`` there, not 1.

    Parameters
    ----------
    ref, test, weights
        As :func:`smape`; ``ref`` (the table) sets the floor, so unlike Eq. 6 this is not
        symmetric in its arguments.
    fraction
        The floor as a fraction of ``ref``'s mean absolute value per channel; finite, > 0.

    Returns
    -------
    float
        In ``[0, 2]``; equal to :func:`smape` where no denominator falls below the floor.
    """
    if not (math.isfinite(fraction) and fraction > 0.0):
        raise ValueError(f"fraction must be a finite positive number, got {fraction!r}")
    a, b, w = _check_values(ref, test, weights)
    absa = np.abs(a)
    if w is None:
        scale = absa.mean(axis=0)
    else:
        scale = np.sum(w * absa, axis=0) / np.sum(w)
    num = np.abs(a - b)
    den = np.maximum(absa + np.abs(b), fraction * scale)
    # num <= |a| + |b| <= den, so each term is in [0, 1]; den is 0 only where the reference
    # channel is 0 everywhere (no scale: the floor is 0, Eq. 6) and the test value is 0: 0/0,
    # agreement, as in :func:`smape`.
    terms = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    return 2.0 * _mean(terms, w)


def brdf_mae(ref: np.ndarray, test: np.ndarray, *, weights: np.ndarray | None = None) -> float:
    """Mean absolute error of BRDF values, ``1/(N C) sum_k |f_k - f^_k|``, in 1/sr.

    Same inputs and checks as :func:`smape`; ``weights`` weight the pairs. Unlike SMAPE it
    depends on the BRDF's scale, so bright specular peaks dominate it.
    """
    a, b, w = _check_values(ref, test, weights)
    return _mean(np.abs(a - b), w)
