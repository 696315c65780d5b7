"""Multiply-adds and bytes read per evaluation of a ``train.btf`` model (:mod:`models.counts`),
from its ``model.json`` alone (no textures, no torch)."""

from __future__ import annotations

from typing import Any

from materials.btf.lafortune import LOBE_PARAMS, LOBES
from models.counts import BILINEAR_TAPS, FLOAT_BYTES, dense_counts


def btf_counts(doc: dict[str, Any]) -> dict[str, int | None]:
    """``{"macs_per_eval", "bytes_per_eval"}`` of a ``train.btf`` ``model.json``
    (:mod:`models.counts`), for one :meth:`models.btf.fused.FusedBtf.eval` at arbitrary
    ``uv``: the dense layers' multiply-adds (NeuMIP's MLP; the student's coarse and fine
    MLPs), and the bytes read: every weight and bias, plus per lookup NeuMIP's texture
    bilinearly (4 texels), the student's coarse texture at one texel and its fine texture
    bilinearly, Lafortune's 55 parameters at the nearest texel. The channels are the first
    layers' inputs less the direction features. ``None`` for both for a document of
    another shape."""
    try:
        kind = doc["architecture"]["model"]
        layers = doc.get("layers") or {}
        shapes = {k: (len(v["weight"][0]), len(v["weight"])) for k, v in layers.items()}
        macs, net_bytes = dense_counts(shapes.values())
        if kind == "neumip":
            texels = BILINEAR_TAPS * (shapes["hidden0"][0] - 4)
        elif kind == "c2f":
            coarse = shapes["coarse1"][0] - 9  # [coarse texture, wi, wo, h]
            fine = shapes["fine1"][0] - shapes["coarse2"][1]  # [z, fine texture]
            texels = coarse + BILINEAR_TAPS * fine
        elif kind == "lafortune":
            texels = 3 + LOBES * LOBE_PARAMS
        else:
            return {"macs_per_eval": None, "bytes_per_eval": None}
    except (KeyError, TypeError, IndexError, AttributeError):
        return {"macs_per_eval": None, "bytes_per_eval": None}
    return {"macs_per_eval": macs, "bytes_per_eval": net_bytes + FLOAT_BYTES * texels}
