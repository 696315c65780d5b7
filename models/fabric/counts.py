"""Multiply-adds and bytes read per evaluation of a ``train.fabric`` model
(:mod:`models.counts`), from its ``model.json`` alone (no torch)."""

from __future__ import annotations

from typing import Any

from models.counts import BILINEAR_TAPS, FLOAT_BYTES, dense_counts

#: Appearance parameters that join ``z`` in the code with ``param_skip``.
N_PARAMS = 5


def fabric_counts(doc: dict[str, Any]) -> dict[str, int | None]:
    """``{"macs_per_eval", "bytes_per_eval"}`` of a ``matforge.fabric-model/1`` document
    for one evaluation of the decoder (:func:`models.fabric.fused.fused_decoder`): every
    decoder layer's ``in * out`` multiply-adds and float32 weights and biases, less
    ``spatial1``'s columns of the material's code ``z`` (``latent_dim``, plus the 5
    parameters with ``param_skip``), which the kernel folds into that layer's bias; plus
    the phase grid's 4 bilinear taps per phase channel. ``None`` for both for a document
    of another shape."""
    try:
        arch = doc["architecture"]
        z_dim = int(arch["latent_dim"]) + (N_PARAMS if arch.get("param_skip") else 0)
        phase = int(arch.get("phase_channels") or 0)
        shapes = {k: (len(v["weight"][0]), len(v["weight"])) for k, v in doc["decoder"].items()}
        n_in, n_out = shapes["spatial1"]
        shapes["spatial1"] = (n_in - z_dim, n_out)
        macs, net_bytes = dense_counts(shapes.values())
    except (KeyError, TypeError, IndexError, ValueError, AttributeError):
        return {"macs_per_eval": None, "bytes_per_eval": None}
    return {
        "macs_per_eval": macs,
        "bytes_per_eval": net_bytes + FLOAT_BYTES * BILINEAR_TAPS * phase,
    }
