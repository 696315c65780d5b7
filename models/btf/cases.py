"""Failure cases of BTF models (issue 13, section 3): where a compact BTF is expected to fail.

A slice ``(wi, wo)`` belongs to

- ``shadowing`` when the light is at least :data:`SHADOW_THETA` degrees from the patch
  normal: on the displaced relief of :mod:`materials.btf.surfaces` long cast shadows and
  masking dominate there (Xu et al. name "strong shadowing" as a failure of the compact
  models);
- ``specular`` when the half vector ``normalize(wi + wo)`` is within :data:`SPECULAR_DEG`
  degrees of the normal: the view is near the light's mirror direction, where a glossy
  surface's highlight is;
- ``rest`` when it is in neither (the two may overlap; ``rest`` is disjoint from both).

The thresholds avoid the angles of both direction sets of :mod:`materials.btf.directions`
(the ``small`` set's 0/30/60 degrees and its half vectors at 0, 15 and 16 degrees; the
UBO rings at multiples of 11.25 degrees), so float rounding cannot move a slice between
cases.

:func:`case_errors` gives each case's mean L1 (texels and channels; every slice has the
same size, so this is the mean of the slices' L1) and its relative L1: that over the mean
``|BTF|`` of the same slices, comparable between cases whose radiance differs by orders of
magnitude (a highlight against a shadow).
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
#: The cases, in the order reported.
CASES = ("shadowing", "specular", "rest")


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
