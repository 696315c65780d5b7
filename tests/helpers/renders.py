"""Comparing two renders of the same estimator computed by different code.

Our Python integrators and Mitsuba's C++ ``path`` run the same estimator with the same
random numbers, but through different instruction sequences (and a different LLVM on
another machine may fuse or reorder differently). So their images agree to float32
rounding, not bit for bit -- and where a rounding difference flips a discrete decision
(a Russian-roulette draw, a ``sample1 < weight`` test), one path takes another branch and
that pixel differs by Monte Carlo noise. The check: almost every pixel agrees to ``rtol``
(about 8 float32 ULPs at 1e-6), and the few that do not are few.
"""

from __future__ import annotations

import numpy as np

#: Relative tolerance per pixel: float32 rounding accumulated along a path.
RTOL = 1e-6
#: Absolute floor, for pixels near black.
ATOL = 1e-7
#: Largest share of pixels allowed to differ by more (paths whose branch flipped).
MAX_FLIPPED = 0.005


def assert_same_render(
    a: np.ndarray, b: np.ndarray, *, rtol: float = RTOL, max_flipped: float = MAX_FLIPPED
) -> None:
    """Assert that two ``(H, W, C)`` renders of the same estimator agree as the module
    docstring says; the message reports the share of differing pixels and the largest
    relative difference."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    assert a.shape == b.shape, (a.shape, b.shape)
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    close = np.isclose(a, b, rtol=rtol, atol=ATOL).all(axis=-1)
    flipped = 1.0 - float(close.mean())
    rel = np.abs(a - b) / np.maximum(np.abs(b), ATOL)
    assert flipped <= max_flipped, (
        f"{flipped:.2%} of pixels differ by more than rtol={rtol:g} (allowed "
        f"{max_flipped:.2%}); largest relative difference {rel.max():.3g}"
    )


def own_render_seconds(store: object, job: object) -> float:
    """A finished render job's own time, as its result rows report it: ``render_seconds``
    of its manifest's ``timings.measured`` (its passes less JIT compilation)."""
    import json

    digest = getattr(job, "manifest_digest", None)
    assert digest, f"job {getattr(job, 'id', '?')} has no manifest"
    manifest = json.loads(store.read(digest))  # type: ignore[attr-defined]
    return float(manifest["timings"]["measured"]["render_seconds"])
