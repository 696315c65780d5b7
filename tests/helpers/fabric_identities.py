"""Identities of the aggregate of Eq. 3-5 (Chen et al. 2024) that hold whatever the yarn
profile, as the tests of ``materials.fabric`` check them: the projected area of a watertight
height field (Eq. 5) and the reciprocity of the numerator of Eq. 3 with ``w = 1``."""

from __future__ import annotations

import math

import numpy as np

from materials.fabric.aggregate import Backend, FootprintQueries, estimate
from materials.fabric.params import FabricParams

#: Polar angles (degrees) of the projected-area check.
AREA_THETAS = (0.0, 30.0, 50.0, 65.0, 75.0)


def direction(theta: float, phi: float) -> np.ndarray:
    """The unit vector at polar angle ``theta`` and azimuth ``phi`` (degrees), z up."""
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def area_over_cosine(
    params: FabricParams, samples: int, seeds: int = 8
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``A_P(wo) / cos theta_o`` (``"area"``) and ``A_in(wi) / cos theta_i``
    (``"area_in"``), both 1 for a watertight height field over whole tiles, at the polar
    angles :data:`AREA_THETAS` (``wo`` at azimuth 25, ``wi`` at 160 degrees) of a footprint
    of side 2 at (0.31, 0.31): the mean over ``seeds`` independent seeds (Dr.Jit backend,
    independent sampler) and its standard error."""
    wo = np.stack([direction(t, 25.0) for t in AREA_THETAS])
    wi = np.stack([direction(t, 160.0) for t in AREA_THETAS])
    n = len(AREA_THETAS)
    q = FootprintQueries(centre=np.full((n, 2), 0.31), size=np.full(n, 2.0), wi=wi, wo=wo)
    runs = [
        estimate(params, q, samples=samples, sampler="independent", seed=s, backend="drjit")
        for s in range(seeds)
    ]
    out = {}
    for attr, w in (("area", wo), ("area_in", wi)):
        vals = np.stack([getattr(r, attr) for r in runs]) / w[:, 2]
        out[attr] = (vals.mean(axis=0), vals.std(axis=0, ddof=1) / math.sqrt(len(runs)))
    return out


def reciprocity_sides(
    params: FabricParams, backend: Backend = "numpy"
) -> tuple[np.ndarray, np.ndarray]:
    """``f_P A_P`` (the numerator of Eq. 3) of four direction pairs ``(wi, wo)`` and of the
    same pairs swapped, with the same sample points (seed 5, 1024 samples): equal to
    rounding when ``params.w = 1``, on either estimator backend."""
    a = np.stack([direction(t, p) for t, p in ((20, 10), (50, 100), (70, 200), (35, 300))])
    b = np.stack([direction(t, p) for t, p in ((60, 250), (15, 40), (45, 20), (80, 130))])
    centre, size = np.tile([0.2, 0.7], (4, 1)), np.full(4, 0.5)
    fwd = estimate(
        params, FootprintQueries(centre, size, a, b), samples=1024, seed=5, backend=backend
    )
    bwd = estimate(
        params, FootprintQueries(centre, size, b, a), samples=1024, seed=5, backend=backend
    )
    return fwd.mean * fwd.area[:, None], bwd.mean * bwd.area[:, None]
