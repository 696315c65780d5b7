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

Options of the second pass (issue 12; :class:`SpatialEncoding`), each off by default so the
paper's encoding above stays the default:

- ``size: "log"``: ``u = ln(size / SIZE_LOG_MIN) / ln(SIZE_MAX / SIZE_LOG_MIN)`` clamped to
  ``[0, 1]`` (sizes below :data:`SIZE_LOG_MIN` = 0.01 tile share the first bin). The strata
  mapping puts 0.04 and 0.125 tile at ``u`` = 0.02 and 0.06, under one bin; the log mapping
  at 0.22 and 0.41, 1.5 bins apart, where a render's pixel footprints lie;
- ``centre: "periodic"``: a periodic one-blob with ``centre_bins`` bins: the distance to a
  bin centre is taken modulo 1 (into ``[-1/2, 1/2)``), so ``u`` = 0.001 and 0.999 get nearly
  the same code and the tile border has no seam (the plain one-blob gives them disjoint
  codes).

Phase taps (:func:`phase_taps`): the four wrap-around bilinear taps of an ``(h, w)`` feature
grid of the tile at a footprint centre, for the phase-aware features of
:mod:`models.fabric.networks`; the gathers are the backends' own.

The formulas are written once over a small :class:`Ops` namespace, so numpy, torch and
Dr.Jit (the fused kernel of :mod:`models.fabric.fused`) share them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

#: Bins per one-blob input (Sec. 4.2: "extending them from 3 to 24 channels").
BINS = 8
#: Largest footprint size in tile units (Sec. 5.1: ``[L_t, 5 L_t]``).
SIZE_MAX = 5.0
#: Smallest footprint size the log size encoding resolves, tile units.
SIZE_LOG_MIN = 0.01
#: Centre encodings and size encodings (the first of each is the paper's).
CENTRE_ENCODINGS: tuple[str, ...] = ("one_blob", "periodic")
SIZE_ENCODINGS: tuple[str, ...] = ("strata", "log")


@dataclass(frozen=True)
class SpatialEncoding:
    """How a footprint is encoded: ``centre`` and ``size`` mappings, bins of each."""

    centre: str = "one_blob"
    size: str = "strata"
    bins: int = BINS
    centre_bins: int = BINS

    def __post_init__(self) -> None:
        if self.centre not in CENTRE_ENCODINGS:
            raise ValueError(
                f"centre encoding must be one of {CENTRE_ENCODINGS}, got {self.centre!r}"
            )
        if self.size not in SIZE_ENCODINGS:
            raise ValueError(f"size encoding must be one of {SIZE_ENCODINGS}, got {self.size!r}")

    @property
    def channels(self) -> int:
        """Channels of the encoded footprint: ``2 centre_bins + bins``."""
        return 2 * self.centre_bins + self.bins


class Ops(NamedTuple):
    """Element-wise operations of one array backend; ``b`` of min/max is a Python float."""

    floor: Callable[[Any], Any]
    exp: Callable[[Any], Any]
    minimum: Callable[[Any, float], Any]
    maximum: Callable[[Any, float], Any]
    log: Callable[[Any], Any] = np.log


NUMPY_OPS = Ops(np.floor, np.exp, np.minimum, np.maximum, np.log)


def torch_ops() -> Ops:
    """:class:`Ops` of torch (imported on demand)."""
    import torch

    return Ops(torch.floor, torch.exp, torch.clamp_max, torch.clamp_min, torch.log)


def drjit_ops() -> Ops:
    """:class:`Ops` of Dr.Jit (imported on demand)."""
    import drjit as dr

    return Ops(dr.floor, dr.exp, dr.minimum, dr.maximum, dr.log)


def wrap_unit(ops: Ops, x: Any) -> Any:
    """A footprint centre coordinate wrapped into ``[0, 1)`` (the tile is periodic)."""
    return x - ops.floor(x)


def size_unit(ops: Ops, size: Any) -> Any:
    """Footprint size (tile units) to ``[0, 1]``: each Sec. 5.1 stratum gets half."""
    u = ops.minimum(size, 1.0) * 0.5 + ops.maximum(size - 1.0, 0.0) * (0.5 / (SIZE_MAX - 1.0))
    return ops.minimum(ops.maximum(u, 0.0), 1.0)


def size_unit_log(ops: Ops, size: Any) -> Any:
    """Footprint size (tile units) to ``[0, 1]`` on a log scale from :data:`SIZE_LOG_MIN`
    to :data:`SIZE_MAX`."""
    scale = 1.0 / float(np.log(SIZE_MAX / SIZE_LOG_MIN))
    u = ops.log(ops.maximum(size, SIZE_LOG_MIN) * (1.0 / SIZE_LOG_MIN)) * scale
    return ops.minimum(ops.maximum(u, 0.0), 1.0)


def one_blob_periodic(ops: Ops, u: Any, bins: int) -> list[Any]:
    """Periodic one-blob of a unit input: the distance to each bin centre wrapped into
    ``[-1/2, 1/2)`` (the tile repeats), then the one-blob Gaussian."""
    out = []
    for i in range(bins):
        d = u - (i + 0.5) / bins
        d = (d - ops.floor(d + 0.5)) * float(bins)
        out.append(ops.exp(d * d * -0.5))
    return out


def one_blob(ops: Ops, u: Any, bins: int = BINS) -> list[Any]:
    """One-blob encoding of a unit input: ``bins`` arrays ``exp(-0.5 ((u - c_i) bins)^2)``."""
    out = []
    for i in range(bins):
        d = (u - (i + 0.5) / bins) * float(bins)
        out.append(ops.exp(d * d * -0.5))
    return out


def spatial_features(
    ops: Ops, cx: Any, cy: Any, size: Any, bins: int = BINS, enc: SpatialEncoding | None = None
) -> list[Any]:
    """The encoded footprint, in order cx bins, cy bins, size bins.

    Without ``enc`` the paper's ``3 * bins`` one-blob channels; with it
    ``enc.channels`` channels (``enc.bins`` replaces ``bins``).
    """
    if enc is None:
        enc = SpatialEncoding(bins=bins, centre_bins=bins)
    if enc.centre == "periodic":
        centre = one_blob_periodic(ops, cx, enc.centre_bins) + one_blob_periodic(
            ops, cy, enc.centre_bins
        )
    else:
        centre = one_blob(ops, wrap_unit(ops, cx), enc.centre_bins) + one_blob(
            ops, wrap_unit(ops, cy), enc.centre_bins
        )
    u = size_unit_log(ops, size) if enc.size == "log" else size_unit(ops, size)
    return centre + one_blob(ops, u, enc.bins)


def phase_taps(ops: Ops, cx: Any, cy: Any, h: int, w: int) -> list[tuple[Any, Any]]:
    """Four ``(flat index, weight)`` taps of wrap-around bilinear sampling of an ``(h, w)``
    grid over the tile at footprint centres ``(cx, cy)`` (tile units, any real).

    Grid conventions are the encoder input's (:func:`models.fabric.networks.map_tensor`):
    row 0 at the top (``t = 1``), column 0 at ``s = 0``; a cell ``(r, c)`` of a stride-``k``
    feature map sits at ``s = c / w``, ``t = 1 - r / h`` (the trunk's strided convolutions
    centre output ``c`` on input pixel ``k c``, to within half an input pixel). Indices are
    float arrays holding integers, ``r w + c`` in ``[0, h w)``; the weights sum to 1.
    """
    x = wrap_unit(ops, cx) * float(w)
    y = (1.0 - wrap_unit(ops, cy)) * float(h)
    x0, y0 = ops.floor(x), ops.floor(y)
    fx, fy = x - x0, y - y0

    def wrap(i: Any, n: int) -> Any:
        return i - ops.floor(i * (1.0 / n)) * float(n)

    c0, c1 = wrap(x0, w), wrap(x0 + 1.0, w)
    r0, r1 = wrap(y0, h), wrap(y0 + 1.0, h)
    return [
        (r0 * float(w) + c0, (1.0 - fx) * (1.0 - fy)),
        (r0 * float(w) + c1, fx * (1.0 - fy)),
        (r1 * float(w) + c0, (1.0 - fx) * fy),
        (r1 * float(w) + c1, fx * fy),
    ]


def spatial_features_numpy(
    cx: np.ndarray,
    cy: np.ndarray,
    size: np.ndarray,
    bins: int = BINS,
    enc: SpatialEncoding | None = None,
) -> np.ndarray:
    """``(N, channels)`` float32 encoded footprints of ``(N,)`` arrays (see
    :func:`spatial_features`)."""
    feats = spatial_features(
        NUMPY_OPS,
        np.asarray(cx, np.float32),
        np.asarray(cy, np.float32),
        np.asarray(size, np.float32),
        bins,
        enc,
    )
    return np.stack(feats, axis=-1).astype(np.float32)
