"""The portable BTF model of ``train.btf``: ``model.json`` (``matforge.btf-model/1``) and
``textures.npz``.

``model.json`` (keys sorted on disk)::

    {
      "format": "matforge.btf-model/1",
      "model": "neumip" | "neumip_max" | "c2f" | "lafortune",
      "architecture": {"model": "neumip" | "c2f" | "lafortune", "width", "resolution": [H, W],
                       "channels", "coarse_channels", "fine_channels", "evaluation": [...]},
      "layers": {name: {"weight": [[in] * out], "bias": [out], "activation"}},
      "storage": {"texture_bytes", "network_bytes", "total_bytes"},   # float32
      "training": {params, resolved values, seed, data}
    }

``textures.npz`` holds the neural textures, float32 ``(C, H, W)`` (``texture`` for
NeuMIP; ``coarse_texture`` ``(7, H/2, W/2)`` and ``fine_texture`` for the student), or the
Lafortune parameters ``params`` ``(H, W, 55)`` (layout in :mod:`materials.btf.lafortune`).

Evaluation at texel ``[j, i]`` for light ``wi`` and view ``wo`` (unit, z up), ``relu``
between layers, the last layer linear, the result clamped at 0 (a BTF is not negative):

- NeuMIP: ``x = [texture[:, j, i], wi.x, wi.y, wo.x, wo.y]``; ``hidden0..2``, ``out``;
- c2f: ``z = relu(coarse2(relu(coarse1([coarse_texture[:, j//2, i//2], wi, wo, h]))))``
  with ``h = normalise(wi + wo)``; ``fine2(relu(fine1([z, fine_texture[:, j, i]])))``;
- lafortune: :func:`materials.btf.lafortune.lafortune_eval`.

:func:`read_model` checks a document; :class:`PortableBtf` evaluates whole slices in numpy
(the reference the fused Dr.Jit path and the renders are tested against).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from materials.btf.lafortune import lafortune_eval
from models.btf.networks import Architecture, CoarseToFine, NeuMIP, build_network
from models.fused_mlp import DenseLayer, mlp_numpy
from storage.formats.npz import npz_bytes

FORMAT = "matforge.btf-model/1"
EVALUATION = {
    "neumip": ["x = [texture(u), wi.x, wi.y, wo.x, wo.y]",
               "x = relu(hidden_k(x)) for k = 0, 1, 2", "rgb = max(out(x), 0)"],
    "c2f": ["z = relu(coarse2(relu(coarse1([coarse_texture(u_c), wi, wo, h]))))",
            "rgb = max(fine2(relu(fine1([z, fine_texture(u)]))), 0)"],
    "lafortune": ["rgb = wi.z (rho_d + sum_j rho_s_j max(wo^T M_j wi, 0)^n_j)"],
}  # fmt: skip


def _layer_doc(layer: nn.Linear, activation: str) -> dict[str, Any]:
    return {
        "weight": layer.weight.detach().to(torch.float64).tolist(),
        "bias": layer.bias.detach().to(torch.float64).tolist(),
        "activation": activation,
    }


def network_layers(net: nn.Module) -> dict[str, dict[str, Any]]:
    """The ``layers`` object of a trained network."""
    if isinstance(net, CoarseToFine):
        return {
            "coarse1": _layer_doc(net.coarse1, "relu"),
            "coarse2": _layer_doc(net.coarse2, "relu"),
            "fine1": _layer_doc(net.fine1, "relu"),
            "fine2": _layer_doc(net.fine2, "identity"),
        }
    assert isinstance(net, NeuMIP)
    layers = {}
    for k, h in enumerate(net.hidden):
        assert isinstance(h, nn.Linear)
        layers[f"hidden{k}"] = _layer_doc(h, "relu")
    layers["out"] = _layer_doc(net.out, "identity")
    return layers


def network_textures(net: nn.Module) -> dict[str, np.ndarray]:
    """The neural textures of a trained network, float32."""
    if isinstance(net, CoarseToFine):
        return {
            "coarse_texture": net.coarse_texture.detach().cpu().numpy().astype(np.float32),
            "fine_texture": net.fine_texture.detach().cpu().numpy().astype(np.float32),
        }
    assert isinstance(net, NeuMIP)
    return {"texture": net.texture.detach().cpu().numpy().astype(np.float32)}


def model_document(
    model: str,
    arch: dict[str, Any],
    layers: dict[str, Any],
    textures: dict[str, np.ndarray],
    training: dict[str, Any],
) -> dict[str, Any]:
    """``model.json``; storage counted at float32."""
    tex_bytes = int(sum(t.size for t in textures.values())) * 4
    net_bytes = int(sum(np.size(v["weight"]) + np.size(v["bias"]) for v in layers.values())) * 4
    kind = arch["model"]
    return {
        "format": FORMAT,
        "model": model,
        "architecture": {**arch, "evaluation": EVALUATION[kind]},
        "layers": layers,
        "storage": {
            "texture_bytes": tex_bytes,
            "network_bytes": net_bytes,
            "total_bytes": tex_bytes + net_bytes,
            "note": "float32; the paper's Table 1 counts the same way",
        },
        "training": training,
    }


def textures_bytes(textures: dict[str, np.ndarray]) -> bytes:
    return npz_bytes({k: np.asarray(v, np.float32) for k, v in textures.items()})


def read_model(doc: Any, textures: dict[str, np.ndarray], name: str = "model.json") -> PortableBtf:
    """A checked :class:`PortableBtf`; ``ValueError`` naming ``name`` when malformed."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{name}: not a BTF model (expected format {FORMAT!r})")
    try:
        arch = doc["architecture"]
        kind = arch["model"]
        h, w = (int(v) for v in arch["resolution"])
        layers = {
            k: DenseLayer(
                np.asarray(v["weight"], np.float32), np.asarray(v["bias"], np.float32),
                str(v["activation"]),
            )
            for k, v in doc["layers"].items()
        }  # fmt: skip
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{name}: malformed BTF model: {exc!r}") from None
    need = {
        "neumip": ("texture",), "c2f": ("coarse_texture", "fine_texture"),
        "lafortune": ("params",),
    }.get(kind)  # fmt: skip
    if need is None:
        raise ValueError(f"{name}: unknown BTF model {kind!r}")
    for key in need:
        if key not in textures:
            raise ValueError(f"{name}: textures.npz lacks {key!r}")
    return PortableBtf(model=str(doc.get("model", kind)), kind=kind, resolution=(h, w),
                       layers=layers, textures=textures, doc=doc)  # fmt: skip


@dataclass(frozen=True)
class PortableBtf:
    """A portable BTF model, evaluated in numpy."""

    model: str
    kind: str
    resolution: tuple[int, int]
    layers: dict[str, DenseLayer]
    textures: dict[str, np.ndarray]
    doc: dict[str, Any]

    def slice(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """The ``(H, W, 3)`` float32 slice for one light/view pair, at texel centres."""
        h, w = self.resolution
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        if self.kind == "lafortune":
            p = self.textures["params"].reshape(h * w, -1)
            out = lafortune_eval(p, wi[None, :], wo[None, :])[:, 0, :]
        elif self.kind == "neumip":
            tex = self.textures["texture"].reshape(-1, h * w).T
            ang = np.tile(np.r_[wi[:2], wo[:2]], (h * w, 1))
            x = np.concatenate([tex, ang], axis=1).astype(np.float32)
            names = sorted(k for k in self.layers if k.startswith("hidden")) + ["out"]
            out = mlp_numpy([self.layers[k] for k in names], x)
        else:
            hv = wi + wo
            hv = hv / np.linalg.norm(hv)
            ct = self.textures["coarse_texture"]
            blocks = ct.reshape(ct.shape[0], -1).T
            ang = np.tile(np.r_[wi, wo, hv], (blocks.shape[0], 1))
            z = mlp_numpy([self.layers["coarse1"], self.layers["coarse2"]],
                          np.concatenate([blocks, ang], axis=1).astype(np.float32))  # fmt: skip
            jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
            block = ((jj // 2) * (w // 2) + ii // 2).reshape(-1)
            fine = self.textures["fine_texture"].reshape(-1, h * w).T
            x = np.concatenate([z[block], fine], axis=1).astype(np.float32)
            out = mlp_numpy([self.layers["fine1"], self.layers["fine2"]], x)
        return np.maximum(out, 0.0).reshape(h, w, 3).astype(np.float32)


def torch_network(model: PortableBtf) -> nn.Module:
    """The torch network of a portable NeuMIP or student (e.g. a distillation teacher)."""
    a = model.doc["architecture"]
    arch = Architecture(
        model=model.kind, width=int(a["width"]), resolution=model.resolution,
        channels=int(a.get("channels", 7)), coarse_channels=int(a.get("coarse_channels", 7)),
        fine_channels=int(a.get("fine_channels", 8)),
    )  # fmt: skip
    net = build_network(arch, 0)
    state = {k: torch.from_numpy(v.copy()) for k, v in model.textures.items()}
    for name, layer in model.layers.items():
        state[f"{_module_name(name)}.weight"] = torch.from_numpy(layer.weight.copy())
        state[f"{_module_name(name)}.bias"] = torch.from_numpy(layer.bias.copy())
    net.load_state_dict(state)
    return net.eval()


def _module_name(layer: str) -> str:
    if layer.startswith("hidden"):
        return f"hidden.{layer[len('hidden') :]}"
    return layer


def read_textures(data: bytes) -> dict[str, np.ndarray]:
    """The arrays of ``textures.npz`` bytes."""
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}
