"""Whether a training loss had flattened by its last step, or the schedule ended the fit.

A loss curve is the mean loss per logging interval, in step order. Windows are a tenth of
its points (:data:`WINDOW`, at least one point): ``mid`` around the middle of training,
``prev`` the tenth before the last, ``last`` the last tenth.

- ``second_half_drop = (mean(mid) - mean(last)) / |mean(mid)|``: how much the loss still
  fell over the second half. This is the verdict: the loss has *flattened* when it changed
  by less than ``tolerance`` (default 10 %) over the second half. With a learning rate
  annealed to zero (the presets' cosine decay) the last tenth is flat by construction even
  when the model is far from converged (a 300-step GGX fit: SMAPE 0.73 against 0.20 at 5,000
  steps, yet its last tenth moved 1.2 %), so the end of the curve alone cannot tell an
  under-trained fit from a converged one; a loss still falling steeply in the second half
  can.
- ``last_tenth_drop = (mean(prev) - mean(last)) / |mean(prev)|``: reported beside it.

A loss that rose by more than ``tolerance`` has not settled either. Under
:data:`MIN_POINTS` finite points, or with a non-finite last point, there is no verdict.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from typing import Any

#: Fraction of the curve's points in each compared window.
WINDOW = 0.1
#: Fewest finite points a verdict needs.
MIN_POINTS = 4
#: Default relative change over the second half under which the loss counts as flat.
TOLERANCE = 0.1


def _drop(before: float, after: float) -> float:
    return (before - after) / abs(before) if before != 0 else 0.0


def convergence(loss: Sequence[float | None], *, tolerance: float = TOLERANCE) -> dict[str, Any]:
    """``{"flattened": bool | None, "second_half_drop", "last_tenth_drop", "mid_mean",
    "last_mean", "points", "tolerance", "why"}`` of a loss curve (``None`` and non-finite
    points are left out; see the module docstring).

    Raises ``ValueError`` for a negative ``tolerance``.
    """
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}")
    finite = [float(v) for v in loss if v is not None and math.isfinite(v)]
    out: dict[str, Any] = {"points": len(finite), "tolerance": tolerance}
    if loss and (loss[-1] is None or not math.isfinite(float(loss[-1]))):
        return {**out, "flattened": None, "why": "the last loss is not finite"}
    if len(finite) < MIN_POINTS:
        return {**out, "flattened": None, "why": f"{len(finite)} loss points, need {MIN_POINTS}"}
    n = len(finite)
    k = max(1, round(WINDOW * n))
    start = n // 2 - k // 2
    mid = statistics.fmean(finite[start : start + k])
    last, prev = statistics.fmean(finite[-k:]), statistics.fmean(finite[-2 * k : -k])
    half, tenth = _drop(mid, last), _drop(prev, last)
    flat = abs(half) < tolerance
    verb = "fell" if half >= 0 else "rose"
    why = (
        f"over the second half the loss {verb} {100 * abs(half):.1f} % "
        f"({'<' if flat else '>='} {100 * tolerance:g} %); over the last tenth it moved "
        f"{100 * tenth:.1f} %"
    )
    return {
        **out,
        "flattened": flat,
        "second_half_drop": half,
        "last_tenth_drop": tenth,
        "mid_mean": mid,
        "last_mean": last,
        "why": why,
    }
