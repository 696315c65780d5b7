"""Failure cases of BTF models: where a compact BTF is expected to fail.

Xu et al. name one failure of their coarse-to-fine model (Sec. 6, Fig. 15): **fine
detail**, the texture's finest spatial structure, which the student's 2 x 2 blocks share
a coarse feature for. That is the ``fine_detail`` case here (:func:`fine_detail_error`).
The other cases are ours, chosen by direction, where a compact model can be expected to
struggle; the paper does not name them. A slice ``(wi, wo)`` belongs to

- ``shadowing`` when the light is at least :data:`SHADOW_THETA` degrees from the patch
  normal: on the displaced relief of :mod:`materials.btf.surfaces` long cast shadows and
  masking dominate there;
- ``specular`` when the half vector ``normalize(wi + wo)`` is within :data:`SPECULAR_DEG`
  degrees of the normal: the view is near the light's mirror direction, where a glossy
  surface's highlight is;
- ``rest`` when it is in neither (the two may overlap; ``rest`` is disjoint from both).

The thresholds avoid the angles of both direction sets of :mod:`materials.btf.directions`
(the ``small`` set's 0/30/60 degrees and its half vectors at 0, 15 and 16 degrees; the
UBO rings at multiples of 11.25 degrees), so float rounding cannot move a slice between
cases.

:func:`case_errors` gives each direction case's mean L1 (texels and channels; every slice
has the same size, so this is the mean of the slices' L1) and its relative L1: that over the
mean ``|BTF|`` of the same slices, comparable between cases whose radiance differs by orders
of magnitude (a highlight against a shadow).

``fine_detail`` is a case in space, not in direction: each slice (truth and model) split
into its 2 x 2 block means (what one coarse feature per block can carry) and the detail
left over (each texel minus its block's mean); its L1 is the mean absolute difference of
the two details, its relative L1 that over the truth detail's mean ``|.|``. A model that
drops all detail inside the blocks (a block-constant slice) scores exactly 1, a perfect one
0. It is measured on the held-out slices (else on up to :data:`DETAIL_SLICES` slices evenly
spaced over the BTF).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

#: Light polar angle (degrees) from which a slice counts as strongly shadowed.
SHADOW_THETA = 50.0
#: Half-vector polar angle (degrees) under which a slice counts as near-specular.
SPECULAR_DEG = 12.0
#: The cases by direction, in the order reported.
CASES = ("shadowing", "specular", "rest")
#: The paper's named failure (Fig. 15), a case in space; reported after :data:`CASES`.
DETAIL_CASE = "fine_detail"
#: Most slices the fine-detail case reads when nothing is held out.
DETAIL_SLICES = 512
#: Truth detail below this fraction of the mean |BTF| is no detail (float rounding of a
#: flat slice): the relative figure is ``None`` then.
DETAIL_FLOOR = 1e-6


def case_masks(wi: np.ndarray, wo: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks ``(N,)`` of each case over slices with directions ``wi``, ``wo``
    ``(N, 3)`` (unit vectors, z up)."""
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    shadow = wi[:, 2] < math.cos(math.radians(SHADOW_THETA))
    h = wi + wo
    norm = np.linalg.norm(h, axis=1)
    cos_h = np.divide(h[:, 2], norm, out=np.zeros(len(h)), where=norm > 0)
    specular = cos_h > math.cos(math.radians(SPECULAR_DEG))
    return {"shadowing": shadow, "specular": specular, "rest": ~(shadow | specular)}


def case_errors(
    wi: np.ndarray, wo: np.ndarray, l1: np.ndarray, mean_abs: np.ndarray
) -> list[dict[str, Any]]:
    """Per case, in :data:`CASES` order: ``{"case", "slices", "l1", "relative_l1",
    "definition"}`` from the per-slice L1 ``l1`` and mean ``|BTF|`` ``mean_abs`` (both
    ``(N,)``); ``None`` errors for an empty case."""
    definitions = {
        "shadowing": f"light at least {SHADOW_THETA:g} degrees from the normal",
        "specular": f"half vector within {SPECULAR_DEG:g} degrees of the normal",
        "rest": "neither",
    }
    out = []
    for name, mask in case_masks(wi, wo).items():
        n = int(mask.sum())
        err = float(np.mean(l1[mask])) if n else None
        scale = float(np.mean(mean_abs[mask])) if n else None
        rel = err / max(scale, 1e-12) if err is not None and scale is not None else None
        out.append({"case": name, "slices": n, "l1": err, "relative_l1": rel,
                    "definition": definitions[name]})  # fmt: skip
    return out


#: ``predict(wi, wo)``: a model's ``(H, W, 3)`` slice at texel centres for one light ``wi``
#: and view ``wo`` (``(3,)`` float32 each).
SlicePredictor = Callable[[np.ndarray, np.ndarray], np.ndarray]


def predicted_slice_l1(predict: SlicePredictor, data: Any, indices: np.ndarray) -> np.ndarray:
    """Mean absolute error of ``predict`` on each slice of ``data`` (a
    :class:`models.btf.data.BtfDataset`) in ``indices``: ``(len(indices),)`` float64, in the
    order of ``indices``, over texels and channels, in float64 -- the L1 that ``train.btf``
    reports for its portable models and ``score`` for external ones."""
    out = np.full(len(indices), np.nan)
    where = {int(i): k for k, i in enumerate(indices)}
    for i, rgb in data.iter_slices(indices):
        pred = np.asarray(predict(data.wi[i], data.wo[i]), np.float64)
        if pred.shape != rgb.shape:
            raise ValueError(f"the model's slice is {pred.shape}, the BTF's {rgb.shape}")
        out[where[i]] = float(np.abs(pred - rgb).sum()) / rgb.size
    return out


def slice_mean_abs(data: Any) -> np.ndarray:
    """Mean ``|BTF|`` of each slice of ``data``, ``(len(data),)`` float64."""
    out = np.empty(len(data))
    for i, rgb in data.iter_slices(np.arange(len(data))):
        out[i] = float(np.abs(rgb).sum(dtype=np.float64)) / rgb.size
    return out


def block_detail(img: np.ndarray) -> np.ndarray:
    """``img`` ``(H, W, C)`` (even ``H``, ``W``) less its 2 x 2 block means: the detail that
    a block-constant image does not carry (float64)."""
    a = np.asarray(img, np.float64)
    h, w, c = a.shape
    if h % 2 or w % 2:
        raise ValueError(f"the fine-detail case needs an even resolution, got {w}x{h}")
    blocks = a.reshape(h // 2, 2, w // 2, 2, c).mean(axis=(1, 3), keepdims=True)
    return (a.reshape(h // 2, 2, w // 2, 2, c) - blocks).reshape(h, w, c)


def detail_slices(n: int, held_out: np.ndarray) -> np.ndarray:
    """The slices the fine-detail case reads: the held-out ones, else up to
    :data:`DETAIL_SLICES` evenly spaced over ``n``."""
    if len(held_out):
        return np.asarray(held_out, np.int64)
    k = min(n, DETAIL_SLICES)
    return np.unique(np.linspace(0, n - 1, k).round().astype(np.int64))


def fine_detail_error(predict: SlicePredictor, data: Any, indices: np.ndarray) -> dict[str, Any]:
    """The ``fine_detail`` case (see the module docstring) of ``predict`` over the slices
    ``indices`` of ``data``: ``{"case", "slices", "l1", "relative_l1", "definition"}``;
    ``None`` errors when the resolution is odd or no slice is given."""
    out: dict[str, Any] = {
        "case": DETAIL_CASE,
        "slices": 0,
        "l1": None,
        "relative_l1": None,
        "definition": "the paper's named failure (Fig. 15): each slice less its 2 x 2 block "
        "means, model against truth (relative: over the truth detail's mean |.|; a "
        "block-constant model scores 1)",
    }
    h, w = data.resolution
    if h % 2 or w % 2 or len(indices) == 0:
        return out
    err = scale = whole = 0.0
    count = 0
    for i, rgb in data.iter_slices(indices):
        truth = block_detail(rgb)
        pred = block_detail(np.asarray(predict(data.wi[i], data.wo[i]), np.float64))
        err += float(np.abs(pred - truth).sum())
        scale += float(np.abs(truth).sum())
        whole += float(np.abs(np.asarray(rgb, np.float64)).sum())
        count += truth.size
    # a BTF without detail (a flat plane: rounding only) has no relative figure
    rel = err / scale if scale > DETAIL_FLOOR * whole else None
    return {**out, "slices": len(indices), "l1": err / count, "relative_l1": rel}
