"""Input encodings of the fabric decoder (Chen, Wang & Wang 2024, Sec. 4.2).

Spatial query. A footprint ``P`` is its centre ``(cx, cy)`` and its box side ``size``, in
tile units (``generators.fabric.queries``: centres in ``[0, 1)``, sizes in ``[0, 5]``).
Before encoding each is mapped to the unit interval:

- centres are wrapped, ``x - floor(x)``: the weave tile is periodic, so a renderer may pass
  ``uv * tiles`` unchanged;
- sizes follow the two strata of Sec. 5.1 (``[0, L_t]`` and ``[L_t, 5 L_t]``, 10 samples
  each), each stretched over half the unit interval:
  ``u = 0.5 min(size, 1) + max(size - 1, 0) / 8``, clamped to 1. A plain ``size / 5`` would
  give the small footprints, where the aggregate varies most, under two of the eight bins.

One-blob encoding (Mueller et al. 2019, "Neural Importance Sampling", Sec. 4.3): each unit
input ``u`` becomes ``bins`` values, a Gaussian kernel of standard deviation ``1 / bins``
centred at ``u`` and evaluated at the bin centres ``c_i = (i + 0.5) / bins``:
``e_i = exp(-0.5 ((u - c_i) bins)^2)``. Chen et al. use 8 bins for each of the 3 inputs:
3 -> 24 channels. The value at the nearest centre is at least ``exp(-1/8)``; the argmax is
the bin containing ``u``.

The formulas are written once over a small :class:`Ops` namespace, so numpy, torch and
Dr.Jit (the fused kernel of :mod:`models.fabric.fused`) share them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

#: Bins per one-blob input (Sec. 4.2: "extending them from 3 to 24 channels").
BINS = 8
#: Largest footprint size in tile units (Sec. 5.1: ``[L_t, 5 L_t]``).
SIZE_MAX = 5.0


class Ops(NamedTuple):
    """Element-wise operations of one array backend; ``b`` of min/max is a Python float."""

    floor: Callable[[Any], Any]
    exp: Callable[[Any], Any]
    minimum: Callable[[Any, float], Any]
    maximum: Callable[[Any, float], Any]


NUMPY_OPS = Ops(np.floor, np.exp, np.minimum, np.maximum)


def torch_ops() -> Ops:
    """:class:`Ops` of torch (imported on demand)."""
    import torch

    return Ops(torch.floor, torch.exp, torch.clamp_max, torch.clamp_min)


def drjit_ops() -> Ops:
    """:class:`Ops` of Dr.Jit (imported on demand)."""
    import drjit as dr

    return Ops(dr.floor, dr.exp, dr.minimum, dr.maximum)


def wrap_unit(ops: Ops, x: Any) -> Any:
    """A footprint centre coordinate wrapped into ``[0, 1)`` (the tile is periodic)."""
    return x - ops.floor(x)


def size_unit(ops: Ops, size: Any) -> Any:
    """Footprint size (tile units) to ``[0, 1]``: each Sec. 5.1 stratum gets half."""
    u = ops.minimum(size, 1.0) * 0.5 + ops.maximum(size - 1.0, 0.0) * (0.5 / (SIZE_MAX - 1.0))
    return ops.minimum(ops.maximum(u, 0.0), 1.0)


def one_blob(ops: Ops, u: Any, bins: int = BINS) -> list[Any]:
    """One-blob encoding of a unit input: ``bins`` arrays ``exp(-0.5 ((u - c_i) bins)^2)``."""
    out = []
    for i in range(bins):
        d = (u - (i + 0.5) / bins) * float(bins)
        out.append(ops.exp(d * d * -0.5))
    return out


def spatial_features(ops: Ops, cx: Any, cy: Any, size: Any, bins: int = BINS) -> list[Any]:
    """The ``3 * bins`` one-blob channels of a footprint, in order cx bins, cy bins, size bins."""
    return (
        one_blob(ops, wrap_unit(ops, cx), bins)
        + one_blob(ops, wrap_unit(ops, cy), bins)
        + one_blob(ops, size_unit(ops, size), bins)
    )


def spatial_features_numpy(
    cx: np.ndarray, cy: np.ndarray, size: np.ndarray, bins: int = BINS
) -> np.ndarray:
    """``(N, 3 * bins)`` float32 one-blob channels of ``(N,)`` footprint arrays."""
    feats = spatial_features(
        NUMPY_OPS,
        np.asarray(cx, np.float32),
        np.asarray(cy, np.float32),
        np.asarray(size, np.float32),
        bins,
    )
    return np.stack(feats, axis=-1).astype(np.float32)
