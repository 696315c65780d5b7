"""The portable model format ``model.json`` and its pure-numpy reference evaluator.

``model.json`` (``"format": "matforge.brdf-model/1"``) holds everything needed to evaluate a
trained ``train.brdf`` model without torch: the architecture, every weight as nested float
lists (the float32 values written exactly, as float64 JSON numbers), and the per-material
parameters, already constrained. :func:`eval_portable` is the reference implementation of
the format; the fused Dr.Jit kernel and the Mitsuba BSDF are tested against it.
``model.pt`` (:func:`checkpoint_bytes`) is the torch checkpoint of the same model.

Document (keys sorted on disk)::

    {
      "format": "matforge.brdf-model/1",
      "model": "hybrid" | "neural" | "analytic",
      "architecture": {
        "model": <as above>, "width": W, "depth": D, "latent_dim": L,
        "per_material_params": 7 + L (hybrid, analytic: L = 0) | L (neural),
        "hidden_activation": "relu",
        "input_encoding": [names of the MLP inputs, in order],
        "output_heads": [{"name", "slice": [start, stop], "activation"}, ...],
        "frames": F (neural: 3) | 0,
        "analytic": {"diffuse", "specular", "shadowing", "fresnel"} | null (neural)
      },
      "network": null (analytic) | {
        "layers": [{"weight": [[...] * in] * out, "bias": [...] * out}, ...],   # D + 1
        "frame": null | {"weight": [[...] * L] * 6F, "bias": [...] * 6F}       # neural
      },
      "materials": [{"name", "family", "kd": [r, g, b] | null, "eta": [r, g, b] | null,
                     "alpha": a | null, "z": [...] * L}, ...],
      "training": {provenance: resolved parameters, seed, dataset; no timings}
    }

Evaluation of material ``m`` at a pair ``(wi, wo)`` (unit vectors, local frame, z up), in
float64; pairs with ``wi.z <= 0`` or ``wo.z <= 0`` give 0 (the network is not evaluated):

1. ``f_a = kd / pi + D G F / (4 wi.z wo.z)`` (Eq. 3; hybrid and analytic): ``h =
   normalize(wi + wo)``; GGX ``D(h.z) = a^2 / (pi (h.z^2 (a^2 - 1) + 1)^2)``; separable Smith
   ``G = G1(wi.z) G1(wo.z)``, ``G1 = 2 / (1 + sqrt(1 + a^2 tan^2))``; ``F`` the exact
   unpolarised Fresnel reflectance of the real IOR ``eta`` (per channel) at
   ``cos_d = dot(wi, h)``. These are :mod:`materials.microfacet`'s ``ndf``, ``smith_g2``
   (``"separable"``) and ``fresnel_conductor`` with ``k = 0``.
2. MLP (hybrid, neural): ``x_0`` = the inputs in ``input_encoding`` order;
   ``x_{k+1} = relu(W_k x_k + b_k)`` for the hidden layers, the last layer linear.
   Hybrid inputs: ``wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, z_0 .. z_{L-1}``.
   Neural inputs: for each frame ``j = 0..F-1``: ``wi.t_j, wi.b_j, wi.n_j, wo.t_j, wo.b_j,
   wo.n_j`` (the directions in frame ``j``), then ``z``. Frame ``j`` from ``r = W_f z + b_f``:
   ``n = r[6j:6j+3] / max(|.|, 1e-12)``, ``t' = r[6j+3:6j+6] - (r[6j+3:6j+6] . n) n``,
   ``t = t' / max(|t'|, 1e-12)``, ``b = n x t``; ``wi.t_j = dot(wi, t)`` and so on.
3. Heads: hybrid ``f_c = exp(out[0:3])``, ``f_g = sigmoid(out[3:6])``,
   ``f = f_c + f_g * f_a`` (Eq. 1); neural ``f = exp(out[0:3])``; analytic ``f = f_a``.

Units: plain BRDF values in 1/sr, linear RGB, no cosine factor.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from materials import microfacet as mf
from models.brdf.networks import (
    NEURAL_FRAMES,
    Architecture,
    BrdfModel,
    ModelType,
    raw_from_constrained,
)

FORMAT = "matforge.brdf-model/1"
ANALYTIC_SPEC = {
    "diffuse": "lambert: kd / pi",
    "specular": "ggx: D G F / (4 cos_i cos_o)",
    "shadowing": "smith_separable: G1(wi) G1(wo)",
    "fresnel": "dielectric_exact: real RGB IOR eta, at cos_d = dot(wi, h)",
}


def input_encoding(arch: Architecture) -> list[str]:
    """Names of the MLP inputs in order (see the module docstring)."""
    z = [f"z{k}" for k in range(arch.latent_dim)]
    if arch.model == "hybrid":
        return ["wi.x", "wi.y", "wi.z", "wo.x", "wo.y", "wo.z", *z]
    if arch.model == "neural":
        frames = [f"{d}.{a}{j}" for j in range(NEURAL_FRAMES) for d in ("wi", "wo") for a in "tbn"]
        return [*frames, *z]
    return []


def _heads(model: ModelType) -> list[dict[str, Any]]:
    if model == "hybrid":
        return [
            {"name": "f_c", "slice": [0, 3], "activation": "exp"},
            {"name": "f_g", "slice": [3, 6], "activation": "sigmoid"},
        ]
    if model == "neural":
        return [{"name": "f", "slice": [0, 3], "activation": "exp"}]
    return []


def _floats(t: torch.Tensor) -> Any:
    return t.detach().to(torch.float64).cpu().tolist()


def to_portable(
    model: BrdfModel,
    names: Sequence[str],
    families: Sequence[str],
    training: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``model.json`` document of ``model`` whose materials are ``names`` in order."""
    arch = model.arch
    if len(names) != model.n_materials or len(families) != model.n_materials:
        raise ValueError("one name and one family per material")
    network = None
    if model.mlp is not None:
        network = {
            "layers": [
                {"weight": _floats(layer.weight), "bias": _floats(layer.bias)}
                for layer in model.mlp.linears()
            ],
            "frame": None
            if model.frame is None
            else {"weight": _floats(model.frame.weight), "bias": _floats(model.frame.bias)},
        }
    with torch.no_grad():
        if arch.model != "neural":
            kd, eta, alpha = model.analytic_params()
        z = model.z if arch.model != "analytic" else torch.zeros(model.n_materials, 0)
    materials = []
    for i, (name, family) in enumerate(zip(names, families, strict=True)):
        analytic = arch.model != "neural"
        materials.append(
            {
                "name": name,
                "family": family,
                "kd": _floats(kd[i]) if analytic else None,
                "eta": _floats(eta[i]) if analytic else None,
                "alpha": float(alpha[i, 0]) if analytic else None,
                "z": _floats(z[i]),
            }
        )
    return {
        "format": FORMAT,
        "model": arch.model,
        "architecture": {
            **arch.as_dict(),
            "per_material_params": arch.per_material_params,
            "hidden_activation": "relu" if arch.model != "analytic" else None,
            "input_encoding": input_encoding(arch),
            "output_heads": _heads(arch.model),
            "frames": NEURAL_FRAMES if arch.model == "neural" else 0,
            "analytic": ANALYTIC_SPEC if arch.model != "neural" else None,
        },
        "network": network,
        "materials": materials,
        "training": training or {},
    }


def check_document(doc: dict[str, Any]) -> Architecture:
    """The architecture of a ``model.json`` document; ``ValueError`` if it is not one."""
    if doc.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} document (format {doc.get('format')!r})")
    a = doc["architecture"]
    return Architecture(a["model"], a["width"], a["depth"], a["latent_dim"])


def material_entry(doc: dict[str, Any], name: str) -> dict[str, Any]:
    """A copy of material ``name``'s entry of ``doc["materials"]``; ``ValueError`` naming
    the model's materials if there is none."""
    for m in doc["materials"]:
        if m["name"] == name:
            return dict(m)
    known = ", ".join(m["name"] for m in doc["materials"])
    raise ValueError(f"no material {name!r} in the model; it has {known}")


def _mlp(layers: list[dict[str, Any]], x: np.ndarray) -> np.ndarray:
    for k, layer in enumerate(layers):
        x = x @ np.asarray(layer["weight"], np.float64).T + np.asarray(layer["bias"], np.float64)
        if k < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return x


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def neural_frames(frame: dict[str, Any], z: np.ndarray) -> np.ndarray:
    """The neural model's learned frames for latent ``z``: ``(F, 3, 3)``, rows ``t, b, n``
    of each frame (the ``frame`` module of the document applied to ``z``)."""
    raw = np.asarray(frame["weight"], np.float64) @ z + np.asarray(frame["bias"], np.float64)
    raw = raw.reshape(NEURAL_FRAMES, 2, 3)
    n = _normalize(raw[:, 0])
    t = _normalize(raw[:, 1] - np.sum(raw[:, 1] * n, axis=-1, keepdims=True) * n)
    return np.stack([t, np.cross(n, t), n], axis=-2)  # (F, 3, 3) rows t, b, n


def eval_portable(doc: dict[str, Any], material: str, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Evaluate material ``material`` of a ``model.json`` document at ``(N, 3)`` pairs.

    Returns ``(N, 3)`` float64 plain BRDF values in 1/sr; 0 where either direction is at or
    below the horizon. Reproduces the torch model's forward (see the module docstring).
    """
    arch = check_document(doc)
    mat = material_entry(doc, material)
    wi = np.asarray(wi, np.float64)
    wo = np.asarray(wo, np.float64)
    if wi.ndim != 2 or wi.shape[1] != 3 or wi.shape != wo.shape:
        raise ValueError(f"wi and wo must both have shape (N, 3), got {wi.shape} and {wo.shape}")
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    out = np.zeros((len(wi), 3))
    i, o = wi[above], wo[above]
    f_a = np.zeros((len(i), 3))
    if arch.model != "neural":
        eta = np.asarray(mat["eta"], np.float64)
        fresnel: Callable[[np.ndarray], np.ndarray] = lambda c: mf.fresnel_conductor(c, eta, 0.0)  # noqa: E731
        f_a = np.asarray(mat["kd"], np.float64) / np.pi + mf.specular_brdf(
            i, o, float(mat["alpha"]), fresnel, distribution="ggx", shadowing="separable"
        )
    if arch.model == "analytic":
        out[above] = f_a
        return out
    z = np.asarray(mat["z"], np.float64)
    zb = np.broadcast_to(z, (len(i), len(z)))
    net = doc["network"]
    if arch.model == "hybrid":
        y = _mlp(net["layers"], np.concatenate([i, o, zb], axis=1))
        with np.errstate(over="ignore"):
            f_g = 1.0 / (1.0 + np.exp(-y[:, 3:6]))
        out[above] = np.exp(y[:, 0:3]) + f_g * f_a
        return out
    rot = neural_frames(net["frame"], z)
    li = np.einsum("fij,nj->nfi", rot, i)
    lo = np.einsum("fij,nj->nfi", rot, o)
    x = np.concatenate([li, lo], axis=-1).reshape(len(i), 6 * NEURAL_FRAMES)
    out[above] = np.exp(_mlp(net["layers"], np.concatenate([x, zb], axis=1)))
    return out


# -- loading into torch --------------------------------------------------------------------------


def from_portable(doc: dict[str, Any]) -> tuple[BrdfModel, list[str], list[str]]:
    """A torch model from a ``model.json`` document: ``(model, names, families)``.

    Per-material values go through the inverse constraints, so ``kd``, ``eta`` and ``alpha``
    come back within float32 rounding (values on a range's edge are clamped just inside).
    """
    arch = check_document(doc)
    mats = doc["materials"]
    model = BrdfModel(arch, len(mats))
    with torch.no_grad():
        if model.mlp is not None:
            for layer, rec in zip(model.mlp.linears(), doc["network"]["layers"], strict=True):
                layer.weight.copy_(torch.tensor(rec["weight"]))
                layer.bias.copy_(torch.tensor(rec["bias"]))
            model.z.copy_(torch.tensor([m["z"] for m in mats]).reshape(len(mats), -1))
        if model.frame is not None:
            model.frame.weight.copy_(torch.tensor(doc["network"]["frame"]["weight"]))
            model.frame.bias.copy_(torch.tensor(doc["network"]["frame"]["bias"]))
        if arch.model != "neural":
            kd, eta, alpha = raw_from_constrained(
                torch.tensor([m["kd"] for m in mats], dtype=torch.float64),
                torch.tensor([m["eta"] for m in mats], dtype=torch.float64),
                torch.tensor([[m["alpha"]] for m in mats], dtype=torch.float64),
            )
            model.raw_kd.copy_(kd)
            model.raw_eta.copy_(eta)
            model.raw_alpha.copy_(alpha)
    return model, [m["name"] for m in mats], [m["family"] for m in mats]


def checkpoint_bytes(model: BrdfModel, names: Sequence[str], families: Sequence[str]) -> bytes:
    """``model.pt``: ``torch.save`` of ``{"format", "architecture", "names", "families",
    "state_dict"}`` (deterministic bytes; load with :func:`load_checkpoint`)."""
    buf = io.BytesIO()
    torch.save(
        {
            "format": FORMAT,
            "architecture": model.arch.as_dict(),
            "names": list(names),
            "families": list(families),
            "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
        },
        buf,
    )
    return buf.getvalue()


def load_checkpoint(data: bytes) -> tuple[BrdfModel, list[str], list[str]]:
    """Inverse of :func:`checkpoint_bytes` (``weights_only`` loading: no code runs)."""
    obj = torch.load(io.BytesIO(data), weights_only=True)
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} checkpoint")
    a = obj["architecture"]
    arch = Architecture(a["model"], a["width"], a["depth"], a["latent_dim"])
    model = BrdfModel(arch, len(obj["names"]))
    model.load_state_dict(obj["state_dict"])
    return model, list(obj["names"]), list(obj["families"])
