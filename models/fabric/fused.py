"""Rendering-side use of a ``train.fabric`` model: load, encode a material, decode fast.

Sec. 4.3 of Chen, Wang & Wang 2024: the encoder runs once per material (and again only when
the material is edited); only the decoder runs per shading query. Here the decoder is
traced into Dr.Jit with every weight a literal (:mod:`models.fused_mlp`), so each SIMD lane
evaluates its own network inside whatever kernel consumes the result (a Mitsuba BSDF's
``eval``, or the whole path tracer); the latent is folded into the first layer's bias
(an opaque per-material value by default, so every material shares one compiled kernel).

Interface::

    load_fabric_model(data: bytes) -> FabricModel
        model.json bytes (decoder + training latents; no encoder) or model.pt bytes
        (everything, the encoder included: needed by encode_material).
    material_maps(params: FabricParams, resolution: int) -> (normal, orientation)
        (H, W, 3) float32 maps of one tile, row 0 at the top, exactly as generate.fabric's
        maps/<name>-normal.exr and -orientation.exr (materials.fabric.yarn.rasterize).
    encode_material(model, params, normal_map, orientation_map) -> (code_dim,) float32
        the material's code: its latent z, then the phase grid when the model has phase
        features (``Architecture.code_dim``).
        params: FabricParams or a materials.json params record; maps as above, any size
        (resampled to the model's map_resolution). Torch on the CPU, eval mode.
    decoder_numpy(model, latent, cx, cy, size, wi, wo, *, raw=False) -> (N, 4) float32
        the reference. cx, cy, size (N,) tile units; wi (N, 3), wo (N, 2 or 3) unit vectors
        in the macro frame (z up; wo.z > 0, wi.z < 0 for transmission).
    decoder_drjit(model, latent, float_type=None, *, raw=False, bake_latent=False) -> f
        f(cx, cy, size, wix, wiy, wiz, wox, woy) -> (C_warp, C_weft, S_warp, S_weft), lazy
        Dr.Jit Float arrays; inputs Dr.Jit Floats of one type (or numpy arrays, converted to
        float_type, default the active Mitsuba variant's ``mi.Float``).

Outputs are the components of Eq. 7 in the units of the training data (unit albedos, incident
cosine included, 1/sr); Eq. 8 gives the RGB value: ``kd_warp C_warp + kd_weft C_weft +
ks_warp S_warp + ks_weft S_weft``. With ``raw=True`` the raw network outputs are returned
instead (C and log-mapped S, Eq. 9). Footprint sizes beyond 5 tiles clamp to 5.

Precision: the fused kernel differs from numpy's float32 matmuls only in summation order
(~1e-6 relative on the raw outputs); ``S = expm1(raw) / k`` uses a 3-term series below
``|raw| < 1e-2`` (Dr.Jit has no expm1), which keeps it within ~1e-6 relative of numpy's.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from materials.fabric.params import FabricParams
from materials.fabric.yarn import rasterize
from models.fabric.encoding import NUMPY_OPS, drjit_ops, phase_taps, spatial_features
from models.fabric.networks import (
    COMPONENTS,
    DECODER_LAYERS,
    K_BRDF,
    K_BTDF,
    Architecture,
    components_numpy,
    map_tensor,
    param_vector,
)
from models.fused_mlp import LEAKY_SLOPE, DenseLayer, fused_mlp, mlp_numpy

#: Activation after each decoder layer (``angular3``'s comes after the skip is added).
_ACTIVATION = {name: "leaky_relu" for name in DECODER_LAYERS} | {
    "angular3": "identity",
    "angular5": "identity",
}


@dataclass(frozen=True, eq=False)
class FabricModel:
    """A loaded model: architecture, decoder layers, training latents, optional encoder."""

    arch: Architecture
    layers: dict[str, DenseLayer]
    """Decoder layers by name (:data:`models.fabric.networks.DECODER_LAYERS`)."""
    latents: dict[str, np.ndarray]
    """Training material name -> ``(code_dim,)`` float32 code (the latent, and the phase grid
    when the model has phase features)."""
    params: dict[str, dict[str, Any]]
    """Training material name -> its ``materials.json`` params record."""
    encoder: Any = None
    """The torch :class:`~models.fabric.networks.Encoder` (eval mode), or ``None`` when loaded
    from ``model.json``."""
    data_map_resolution: int | None = None
    """Side of the training data's maps (``model.pt`` of models trained since it was
    recorded; ``None`` otherwise): new materials' maps are rasterised at this side, as the
    training maps were, before the encoder's resampling."""


def load_fabric_model(data: bytes) -> FabricModel:
    """A model from ``model.json`` bytes (no encoder) or ``model.pt`` bytes (with encoder).

    Raises ``ValueError`` for anything else.
    """
    if data[:1] == b"{":
        from models.fabric.portable import FORMAT

        doc = json.loads(data)
        if doc.get("format") != FORMAT:
            raise ValueError(f"not a {FORMAT} document (train.fabric model.json)")
        arch = Architecture.from_dict(doc["architecture"])
        layers = {
            n: DenseLayer(np.array(d["weight"]), np.array(d["bias"]), _ACTIVATION[n])
            for n, d in ((n, doc["decoder"][n]) for n in DECODER_LAYERS)
        }
        mats = doc["materials"]
        latents = {m["name"]: np.array(m["latent"], np.float32) for m in mats}
        return FabricModel(arch, layers, latents, {m["name"]: m["params"] for m in mats})
    import pickle

    from models.fabric.networks import decoder_arrays
    from models.fabric.portable import load_checkpoint

    try:
        net, obj = load_checkpoint(data)
    except (RuntimeError, OSError, KeyError, EOFError, pickle.UnpicklingError) as exc:
        raise ValueError(f"neither a train.fabric model.json nor model.pt: {exc}") from None
    layers = {
        n: DenseLayer(w, b, _ACTIVATION[n]) for n, (w, b) in decoder_arrays(net.decoder).items()
    }
    z = obj["latents"].numpy()
    return FabricModel(
        net.arch,
        layers,
        {n: z[i].astype(np.float32) for i, n in enumerate(obj["names"])},
        dict(zip(obj["names"], obj["params"], strict=True)),
        net.encoder,
        int(obj["data_map_resolution"]) if obj.get("data_map_resolution") else None,
    )


def material_maps(params: FabricParams, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Normal and orientation maps ``(R, R, 3)`` float32, row 0 at the top (as the EXRs)."""
    maps = rasterize(params, resolution)
    return np.ascontiguousarray(maps.normal[::-1]), np.ascontiguousarray(maps.tangent[::-1])


def _param_record(params: FabricParams | Mapping[str, Any]) -> Mapping[str, Any]:
    if isinstance(params, FabricParams):
        return {"alpha": list(params.alpha), "beta": list(params.beta), "w": params.w}
    return params


def encode_material(
    model: FabricModel,
    params: FabricParams | Mapping[str, Any],
    normal_map: np.ndarray,
    orientation_map: np.ndarray,
) -> np.ndarray:
    """The ``(code_dim,)`` float32 code of a material (runs the torch encoder once)."""
    if model.encoder is None:
        raise ValueError(
            "this model was loaded from model.json, which carries no encoder; load the job's "
            "model.pt to encode new materials (the training materials' latents are in "
            "model.latents)"
        )
    import torch

    maps = map_tensor(normal_map, orientation_map, model.arch.map_resolution)
    p = param_vector(_param_record(params))
    with torch.no_grad():
        z = model.encoder(torch.from_numpy(maps)[None], torch.from_numpy(p)[None])
    return z[0].numpy().astype(np.float32)


def _latent(model: FabricModel, latent: np.ndarray | str) -> np.ndarray:
    z = model.latents[latent] if isinstance(latent, str) else np.asarray(latent, np.float32)
    if z.shape != (model.arch.code_dim,):
        raise ValueError(f"latent must have shape ({model.arch.code_dim},), got {z.shape}")
    return z


def decoder_numpy(
    model: FabricModel,
    latent: np.ndarray | str,
    cx: np.ndarray,
    cy: np.ndarray,
    size: np.ndarray,
    wi: np.ndarray,
    wo: np.ndarray,
    *,
    raw: bool = False,
) -> np.ndarray:
    """Reference decoder: ``(N, 4)`` float32 components (or raw outputs); see the module
    docstring. ``latent`` may be a training material's name."""
    code = _latent(model, latent)
    a = model.arch
    z = code[: a.z_dim]
    cx = np.asarray(cx, np.float32).reshape(-1)
    cy = np.asarray(cy, np.float32).reshape(-1)
    wi = np.asarray(wi, np.float32).reshape(-1, 3)
    wo = np.asarray(wo, np.float32)[:, :2]
    feats = np.stack(
        spatial_features(NUMPY_OPS, cx, cy, np.asarray(size, np.float32).reshape(-1),
                         enc=a.encoding), axis=1
    ).astype(np.float32)  # fmt: skip
    L = model.layers
    parts = [np.broadcast_to(z, (len(cx), len(z)))]
    if a.phase_channels:
        g = a.phase_grid
        grid = code[a.z_dim :].reshape(a.phase_channels, g * g)
        sampled = np.zeros((len(cx), a.phase_channels), np.float32)
        for idx, wt in phase_taps(NUMPY_OPS, cx, cy, g, g):
            sampled += wt[:, None] * grid[:, idx.astype(np.int64)].T
        parts.append(sampled)
    x = np.concatenate([*parts, feats], axis=1)
    s = mlp_numpy([L["spatial1"], L["spatial2"]], x)
    h1 = mlp_numpy([L["angular1"]], np.concatenate([s, wi, wo], axis=1))
    pre = mlp_numpy([L["angular2"], L["angular3"]], h1) + h1
    h3 = np.where(pre >= 0, pre, LEAKY_SLOPE * pre).astype(np.float32)
    out = mlp_numpy([L["angular4"], L["angular5"]], h3)
    return out if raw else components_numpy(out, wi[:, 2])


def _expm1(dr: Any, x: Any) -> Any:
    """``exp(x) - 1`` accurate near 0 (3-term series below 1e-2; Dr.Jit has no expm1)."""
    series = x * (1.0 + x * (0.5 + x * (1.0 / 6.0)))
    return dr.select(dr.abs(x) < 1e-2, series, dr.exp(x) - 1.0)


def decoder_drjit(
    model: FabricModel,
    latent: np.ndarray | str,
    float_type: Any = None,
    *,
    raw: bool = False,
    bake_latent: bool = False,
) -> Callable[..., tuple[Any, Any, Any, Any]]:
    """The decoder of one latent as a fused Dr.Jit function (see the module docstring).

    The returned ``f(cx, cy, size, wix, wiy, wiz, wox, woy)`` traces the whole network with
    the weights as literals; nothing is evaluated until the outputs are used. By default
    ``spatial1``'s bias with the latent folded in (``b + W_z z``) is an opaque per-material
    Dr.Jit value, so all materials share one compiled kernel; ``bake_latent=True`` makes it
    literals too (a new kernel per material: LLVM takes ~4 s at width 32, ~30-60 s at 64 on
    2 cores, for no measurable speed gain; ``benchmarks/bench_train_fabric.py``).
    """
    import drjit as dr

    if float_type is None:
        from materials.backend import load_mitsuba

        float_type = load_mitsuba().Float  # the variant's backend: LLVM or CUDA
    code = _latent(model, latent)
    a = model.arch
    z = [float(v) for v in code[: a.z_dim]]
    grid = code[a.z_dim :].astype(np.float32)
    g = a.phase_grid
    L = model.layers
    ops = drjit_ops()
    leaky = lambda x: dr.select(x >= 0.0, x, x * LEAKY_SLOPE)  # noqa: E731
    first = L["spatial1"]
    n_z = len(z)
    # Not baked: b + W_z z per material (float64, rounded once, as fused_mlp's folding),
    # and the remaining one-blob columns with a zero bias, no activation.
    latent_bias = (
        (first.bias.astype(np.float64) + first.weight[:, :n_z].astype(np.float64) @ np.array(z))
        .astype(np.float32)
        .tolist()
    )
    spatial1_free = DenseLayer(first.weight[:, n_z:], np.zeros(first.n_out), "identity")

    def as_float(x: Any) -> Any:
        return x if dr.is_array_v(x) else float_type(np.asarray(x, np.float32))

    def f(cx: Any, cy: Any, size: Any, wix: Any, wiy: Any, wiz: Any, wox: Any, woy: Any) -> Any:
        cx, cy, size, wix, wiy, wiz, wox, woy = (
            as_float(v) for v in (cx, cy, size, wix, wiy, wiz, wox, woy)
        )
        feats = spatial_features(ops, cx, cy, size, enc=a.encoding)
        if a.phase_channels:
            # Phase features: the material's grid, wrap-around bilinear at the centre.
            table = type(cx)(grid)
            dr.make_opaque(table)
            taps = phase_taps(ops, cx, cy, g, g)
            index_type = dr.uint32_array_t(type(cx))
            phase = []
            for p in range(a.phase_channels):
                v = type(cx)(0.0)
                for idx, wt in taps:
                    i = index_type(idx) + p * g * g
                    v = v + wt * dr.gather(type(cx), table, i)
                phase.append(v)
            feats = [*phase, *feats]
        if bake_latent:
            s = fused_mlp([L["spatial1"], L["spatial2"]], [*z, *feats])
        else:
            pre = fused_mlp([spatial1_free], feats)
            s1 = [leaky(p + dr.opaque(type(cx), b)) for p, b in zip(pre, latent_bias, strict=True)]
            s = fused_mlp([L["spatial2"]], s1)
        h1 = fused_mlp([L["angular1"]], [*s, wix, wiy, wiz, wox, woy])
        t = fused_mlp([L["angular2"], L["angular3"]], h1)
        h3 = [leaky(a + b) for a, b in zip(t, h1, strict=True)]
        out = fused_mlp([L["angular4"], L["angular5"]], h3)
        if raw:
            return tuple(out)
        inv_k = dr.select(wiz < 0.0, 1.0 / K_BTDF, 1.0 / K_BRDF)
        c = [dr.select(wiz < 0.0, 0.0, dr.maximum(o, 0.0)) for o in out[:2]]
        s_ = [_expm1(dr, dr.maximum(o, 0.0)) * inv_k for o in out[2:]]
        return (c[0], c[1], s_[0], s_[1])

    return f


__all__ = [
    "COMPONENTS",
    "FabricModel",
    "decoder_drjit",
    "decoder_numpy",
    "encode_material",
    "load_fabric_model",
    "material_maps",
]
