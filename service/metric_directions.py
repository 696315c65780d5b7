"""Which way is better for a metric, from its name: what the dashboard's charts and tables
highlight. Result tables carry names only (``flip``, ``psnr``, ``baseline.rgb.rel``,
``ns_per_eval``), so the direction is read from the words in the name; a name with no
known word has none (``mean_r`` of a render is a measurement, not a score).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, Literal

Direction = Literal["lower", "higher"]

#: Words of metrics where more is better: PSNR (dB), SSIM, rates and speed-ups.
HIGHER = frozenset({"psnr", "ssim", "accuracy", "speedup", "mpaths", "throughput", "r2", "fps"})
#: Words of errors, losses and costs, where less is better.
LOWER = frozenset(
    {
        "flip", "mae", "mse", "rmse", "smape", "loss", "rel", "err", "error", "l1", "l2",
        "lpips", "seconds", "time", "ms", "ns", "us", "memory", "bytes", "mib", "cost",
        "macs",
    }
)  # fmt: skip


def direction(name: str) -> Direction | None:
    """``"lower"``, ``"higher"`` or ``None`` for a metric called ``name``; a rate
    (``..._per_s``, ``.../s``) is higher-is-better whatever it counts."""
    words = [w for w in re.split(r"[^a-z0-9]+", name.lower()) if w]
    if words[-2:] == ["per", "s"] or name.lower().endswith("/s"):
        return "higher"
    if any(w in HIGHER for w in words):
        return "higher"
    if any(w in LOWER for w in words):
        return "lower"
    return None


#: Row labels that aggregate the others (never "the best" of them), also as the first word
#: of a label (``mean test``, ``mean train``: a split's mean).
AGGREGATES = frozenset({"mean", "median", "all", "total"})


def best_labels(rows: Mapping[str, Mapping[str, Any]], names: list[str]) -> dict[str, str]:
    """``{metric: label}`` of the best row of each metric with a direction (numbers only,
    aggregate rows such as ``mean`` left out; no entry when fewer than two rows have a
    number or all are equal)."""
    out = {}
    for name in names:
        sense = direction(name)
        values = {
            label: float(v[name])
            for label, v in rows.items()
            if label not in AGGREGATES
            and label.split(" ")[0] not in AGGREGATES  # "mean test", "mean train"
            and isinstance(v.get(name), int | float)
            and not isinstance(v.get(name), bool)
        }
        if sense is None or len(values) < 2 or len(set(values.values())) == 1:
            continue
        pick = min if sense == "lower" else max
        out[name] = pick(values, key=lambda label: values[label])
    return out
