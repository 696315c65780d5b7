"""``model.json`` (``matforge.fabric-model/1``) and ``model.pt`` of ``train.fabric``.

``model.json`` holds what rendering needs without torch: the architecture, the decoder's
weights as nested float lists (float32 values written exactly as float64 JSON numbers) and
every training material's latent and parameters. The encoder (a ResNet trunk of about 0.8 M
(small) to 2.9 M (paper) weights) is *not* in it: encoding a new material needs
``model.pt`` (:func:`models.fabric.fused.load_fabric_model` accepts either).

Document (keys sorted on disk)::

    {
      "format": "matforge.fabric-model/1",
      "architecture": {
        "encoder_width", "map_resolution", "latent_dim", "mlp_width", "decoder_width",
        "bins",                                   # Architecture fields
        "param_names": [5 names], "components": ["C_warp", "C_weft", "S_warp", "S_weft"],
        "decoder_inputs": "spatial1: latent (L) then one-blob cx, cy, size (3 x bins); "
                          "angular1: spatial feature then wi.x, wi.y, wi.z, wo.x, wo.y",
        "activation": "leaky_relu", "leaky_slope": 0.01,
        "log_k": {"brdf": 100, "btdf": 1000},
        "encoding": {...}, "evaluation": [...]    # prose of the steps below
      },
      "decoder": {layer: {"weight": [[...] * in] * out, "bias": [...] * out}},  # 7 layers
      "materials": [{"name", "pattern", "params": {materials.json params}, "latent": [L]}],
      "training": {provenance: params, resolved values, seed, dataset; no timings}
    }

Evaluation of a latent ``z`` at a query (``cx, cy, size`` tile units; ``wi``, ``wo`` unit,
macro frame, ``wo.z > 0``), with ``a = leaky_relu``:

1. ``e`` = one-blob of ``wrap(cx), wrap(cy), size_unit(size)`` (:mod:`models.fabric.encoding`);
2. ``s = a(spatial2(a(spatial1([z, e]))))``;
3. ``h1 = a(angular1([s, wi.x, wi.y, wi.z, wo.x, wo.y]))``,
   ``h3 = a(angular3(a(angular2(h1))) + h1)``, ``raw = angular5(a(angular4(h3)))``;
4. ``C = max(raw[0:2], 0)`` (0 if ``wi.z < 0``: no diffuse transmission),
   ``S = expm1(max(raw[2:4], 0)) / k``, ``k = 1000`` if ``wi.z < 0`` else 100 (inverse of
   Eq. 9); Eq. 8: ``f = sum albedo_c * component_c``.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from models.fabric.encoding import BINS, SIZE_MAX
from models.fabric.networks import (
    ANGULAR_INPUTS,
    COMPONENTS,
    DECODER_LAYERS,
    K_BRDF,
    K_BTDF,
    LEAKY,
    PARAM_NAMES,
    Architecture,
    FabricNetwork,
)

FORMAT = "matforge.fabric-model/1"
CHECKPOINT_FORMAT = "matforge.fabric-checkpoint/1"


def _floats(t: torch.Tensor) -> Any:
    return t.detach().to(torch.float64).cpu().tolist()


def architecture_doc(arch: Architecture) -> dict[str, Any]:
    """The ``architecture`` object of ``model.json`` (the second-pass options, when set,
    appear as fields and under ``second_pass``)."""
    doc = _paper_architecture_doc(arch)
    extra = {k: v for k, v in arch.as_dict().items() if k not in Architecture().as_dict()}
    if extra:
        doc["second_pass"] = {
            "code": "a material's latent is its code: z (latent_dim), the 5 param_names "
            "values when param_skip is 1, then the phase grid "
            f"(phase_channels x {arch.phase_grid} x {arch.phase_grid}, C order; row 0 at t = 1)",
            "spatial1_inputs": "z (and the params), phase features (phase_channels: the "
            "grid sampled bilinearly with wrap-around at (cx, cy), encoding.phase_taps), "
            "then cx bins, cy bins (centre_bins each), size bins (bins)",
            "centre_encoding": "periodic: exp(-0.5 (wrap(u - c_i) bins)^2), wrap into "
            "[-1/2, 1/2)" if arch.centre_encoding == "periodic" else "one_blob",
            "size_encoding": "log: u = clamp(ln(size / 0.01) / ln(500), 0, 1)"
            if arch.size_encoding == "log" else "strata",
        }  # fmt: skip
    return doc


def _paper_architecture_doc(arch: Architecture) -> dict[str, Any]:
    return {
        **arch.as_dict(),
        "param_names": list(PARAM_NAMES),
        "components": list(COMPONENTS),
        "angular_inputs": list(ANGULAR_INPUTS),
        "decoder_layers": list(DECODER_LAYERS),
        "decoder_inputs": "spatial1: latent (latent_dim) then one-blob cx, cy, size "
        "(3 x bins); angular1: spatial feature (decoder_width) then wi.x, wi.y, wi.z, wo.x, wo.y",
        "activation": "leaky_relu",
        "leaky_slope": LEAKY,
        "log_k": {"brdf": K_BRDF, "btdf": K_BTDF},
        "encoding": {
            "one_blob": f"exp(-0.5 ((u - (i + 0.5) / bins) bins)^2), i < bins (default {BINS})",
            "cx, cy": "u = x - floor(x) (periodic tile)",
            "size": "u = clamp(0.5 min(size, 1) + max(size - 1, 0) / "
            f"{2 * (SIZE_MAX - 1):g}, 0, 1)",
        },
        "evaluation": [
            "s = a(spatial2(a(spatial1([z, onehot]))))",
            "h1 = a(angular1([s, wi.x, wi.y, wi.z, wo.x, wo.y]))",
            "h3 = a(angular3(a(angular2(h1))) + h1)",
            "raw = angular5(a(angular4(h3)))",
            "C = 0 if wi.z < 0 else max(raw[0:2], 0)",
            "S = expm1(max(raw[2:4], 0)) / k, k = 1000 if wi.z < 0 else 100",
        ],
    }


def to_portable(
    net: FabricNetwork,
    names: Sequence[str],
    patterns: Sequence[str],
    records: Sequence[dict[str, Any]],
    latents: np.ndarray,
    training: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``model.json`` document; ``latents`` ``(M, L)`` float32 in ``names`` order."""
    decoder = {
        name: {
            "weight": _floats(getattr(net.decoder, name).weight),
            "bias": _floats(getattr(net.decoder, name).bias),
        }
        for name in DECODER_LAYERS
    }
    materials = [
        {"name": n, "pattern": p, "params": r, "latent": np.asarray(z, np.float64).tolist()}
        for n, p, r, z in zip(names, patterns, records, latents, strict=True)
    ]
    return {
        "format": FORMAT,
        "architecture": architecture_doc(net.arch),
        "decoder": decoder,
        "materials": materials,
        "training": training or {},
    }


def checkpoint_bytes(
    net: FabricNetwork,
    names: Sequence[str],
    records: Sequence[dict[str, Any]],
    latents: np.ndarray,
    data_map_resolution: int | None = None,
) -> bytes:
    """``model.pt``: ``torch.save`` of ``{"format", "architecture", "names", "params",
    "latents", "state_dict"}`` and, when given, ``data_map_resolution``: the side of the
    training data's maps (``generate.fabric``'s ``map_resolution``), so that a renderer
    rasterises a new material's maps as the training maps were made (deterministic bytes;
    :func:`load_checkpoint`)."""
    buf = io.BytesIO()
    extra = {} if data_map_resolution is None else {"data_map_resolution": int(data_map_resolution)}
    torch.save(
        {
            **extra,
            "format": CHECKPOINT_FORMAT,
            "architecture": net.arch.as_dict(),
            "names": list(names),
            "params": list(records),
            "latents": torch.from_numpy(np.asarray(latents, np.float32).copy()),
            "state_dict": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
        },
        buf,
    )
    return buf.getvalue()


def load_checkpoint(data: bytes) -> tuple[FabricNetwork, dict[str, Any]]:
    """Inverse of :func:`checkpoint_bytes`: ``(network in eval mode, the saved dict)``.

    ``weights_only`` loading, so no code runs. Raises ``ValueError`` for another format.
    """
    obj = torch.load(io.BytesIO(data), weights_only=True, map_location="cpu")
    if not isinstance(obj, dict) or obj.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"not a {CHECKPOINT_FORMAT} checkpoint (train.fabric model.pt)")
    net = FabricNetwork(Architecture.from_dict(obj["architecture"]))
    net.load_state_dict(obj["state_dict"])
    return net.eval(), obj
