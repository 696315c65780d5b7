"""Whether a training loss had flattened by its last step.

A loss curve (mean loss per logging interval, in step order) has *flattened* when its last
tenth of training changed from the tenth before it by less than ``tolerance`` of that
tenth's mean: ``|mean(prev) - mean(last)| / |mean(prev)| < tolerance``. A loss still
falling faster is under-trained; one rising by more is not settled either. Windows are
:data:`WINDOW` of the curve's points (at least one each). Under :data:`MIN_POINTS` points
there is no verdict. Noise makes single points useless; window means compare like with like.
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
#: Default relative improvement of the last window under which the loss counts as flat.
TOLERANCE = 0.02


def convergence(loss: Sequence[float | None], *, tolerance: float = TOLERANCE) -> dict[str, Any]:
    """``{"flattened": bool | None, "relative_drop", "last_mean", "prev_mean", "points",
    "why"}`` of a loss curve (``None`` and non-finite points are left out).

    ``flattened`` is ``None`` (with ``why``) when the curve is too short or diverged (a
    non-finite point after the last finite one). Raises ``ValueError`` for a negative
    ``tolerance``.
    """
    if tolerance < 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance}")
    finite = [float(v) for v in loss if v is not None and math.isfinite(v)]
    out: dict[str, Any] = {"points": len(finite), "tolerance": tolerance}
    if loss and (loss[-1] is None or not math.isfinite(float(loss[-1]))):
        return {**out, "flattened": None, "why": "the last loss is not finite"}
    if len(finite) < MIN_POINTS:
        return {**out, "flattened": None, "why": f"{len(finite)} loss points, need {MIN_POINTS}"}
    k = max(1, round(WINDOW * len(finite)))
    last, prev = statistics.fmean(finite[-k:]), statistics.fmean(finite[-2 * k : -k])
    drop = (prev - last) / abs(prev) if prev != 0 else 0.0
    flat = abs(drop) < tolerance
    verb = "fell" if drop >= 0 else "rose"
    why = (
        f"the mean of the last {k} of {len(finite)} points {verb} {100 * abs(drop):.2f} % "
        f"from the {k} before ({'<' if flat else '>='} {100 * tolerance:g} %)"
    )
    return {
        **out,
        "flattened": flat,
        "relative_drop": drop,
        "last_mean": last,
        "prev_mean": prev,
        "why": why,
    }
