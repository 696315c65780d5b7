"""Export your own PyTorch material network to matforge's MLP formats.

:func:`brdf_mlp` writes ``matforge.mlp-brdf/1`` and :func:`btf_mlp` writes
``matforge.mlp-btf/1`` (``docs/formats.md``): one JSON file that ``matforge import`` (or
``POST /api/artifacts``) validates and stores, and that the ``external`` material source
renders through the same fused Dr.Jit kernel as the built-in models::

    {"kind": "render", "params": {"scene": "sphere_env",
     "material": {"external": {"model": "sha256:...", "kind": "brdf"}}}}

Torch is imported only when a module is converted; ``import matforge.export`` does not
import it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from storage.errors import FormatError
from storage.formats.mlp_model import (
    BRDF_FORMAT,
    BTF_FORMAT,
    parse_mlp_document,
    texture_entry,
)

#: torch activation module class name -> format activation name.
_TORCH_ACTIVATIONS = {
    "ReLU": "relu",
    "LeakyReLU": "leaky_relu",
    "Sigmoid": "sigmoid",
    "Softplus": "softplus",
    "Tanh": "tanh",
    "Identity": "identity",
}


def _numpy(x: Any) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().double().numpy()
    return np.asarray(x, np.float64)


def _layers_of(
    module_or_layers: Any, activations: str | Sequence[str] | None
) -> list[dict[str, Any]]:
    """``[{"weight", "bias", "activation"}]`` from an ``nn.Sequential`` of Linear and
    activation modules (nested Sequentials flattened), or from a list of ``nn.Linear`` with
    ``activations`` (one name per layer, or one hidden name with the last layer linear)."""
    if module_or_layers is None:
        return []
    modules: list[Any] = []

    def flatten(m: Any) -> None:
        children = list(m.children()) if hasattr(m, "children") else []
        if type(m).__name__ in ("Sequential", "ModuleList") or isinstance(m, (list, tuple)):
            for c in m if isinstance(m, (list, tuple)) else children:
                flatten(c)
        else:
            modules.append(m)

    flatten(module_or_layers)
    layers: list[dict[str, Any]] = []
    for m in modules:
        name = type(m).__name__
        if name == "Linear":
            if m.bias is None:
                bias = np.zeros(m.out_features)
            else:
                bias = _numpy(m.bias)
            layers.append({"weight": _numpy(m.weight).tolist(), "bias": bias.tolist(),
                           "activation": "identity"})  # fmt: skip
        elif name in _TORCH_ACTIVATIONS:
            if not layers or layers[-1]["activation"] != "identity":
                raise ValueError(f"activation {name} must follow an nn.Linear")
            if name == "LeakyReLU" and abs(float(m.negative_slope) - 0.01) > 1e-12:
                raise ValueError("LeakyReLU: the format's slope is 0.01 (torch's default)")
            if name == "Softplus" and float(m.beta) != 1.0:
                raise ValueError("Softplus: the format's softplus has beta = 1")
            layers[-1]["activation"] = _TORCH_ACTIVATIONS[name]
        elif name != "Dropout":
            raise ValueError(
                f"cannot export a {name} module: give Linear layers and activations of "
                f"{', '.join(_TORCH_ACTIVATIONS)} (put exp or per-output activations in "
                f"output_activation)"
            )
    if activations is not None:
        if isinstance(activations, str):
            acts = [activations] * (len(layers) - 1) + ["identity"]
        else:
            acts = list(activations)
        if len(acts) != len(layers):
            raise ValueError(f"{len(acts)} activations for {len(layers)} layers")
        for layer, act in zip(layers, acts, strict=True):
            layer["activation"] = act
    return layers


def _write(doc: dict[str, Any], path: str | os.PathLike[str]) -> Path:
    out = Path(path)
    try:  # the upload's own check: refuse here what an upload would refuse
        parse_mlp_document(doc, out.name)
    except FormatError as exc:
        raise ValueError(str(exc)) from None
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
    out.write_text(text, encoding="utf-8")
    return out


def brdf_mlp(
    module_or_layers: Any,
    path: str | os.PathLike[str],
    *,
    inputs: Sequence[str | Mapping[str, Any]] = ("wi", "wo"),
    activations: str | Sequence[str] | None = None,
    output_activation: str | Sequence[str] = "identity",
    analytic: Mapping[str, Any] | None = None,
    combine: str | None = None,
    name: str = "",
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write a BRDF network as ``matforge.mlp-brdf/1`` and return the path.

    Parameters
    ----------
    module_or_layers
        A ``torch.nn.Sequential`` of ``nn.Linear`` and activation modules (ReLU, LeakyReLU,
        Sigmoid, Softplus, Tanh, Identity), or a list of ``nn.Linear`` (then give
        ``activations``); ``None`` for no network (``analytic`` alone).
    path
        The file to write (JSON).
    inputs
        The network's input encodings in order: ``wi``, ``wo``, ``wi.xy``, ``wo.xy``, ``h``,
        ``d``, ``cos_i``, ``cos_o``, ``cos_h``, ``cos_d``, or
        ``{"type": "fourier", "input": NAME, "frequencies": [...]}``; directions in the
        local frame, z up (``docs/formats.md``).
    activations
        For a list of Linear layers: one activation per layer, or one name for the hidden
        layers (the last then linear).
    output_activation
        Applied to the network's outputs: a name (``exp``, ``sigmoid``, ...) or one per
        output (the hybrid's ``["exp"] * 3 + ["sigmoid"] * 3``).
    analytic
        ``{"kd": [r, g, b], "alpha": a, "eta": [r, g, b]}``: the Lambert + GGX part ``f_a``
        (exact real-IOR Fresnel), values or tensors.
    combine
        ``"network"`` (``f = y``), ``"sum"`` (``f = y + f_a``), ``"hybrid"`` (``f = y[0:3]
        + y[3:6] f_a``) or ``"analytic"`` (``f = f_a``); default: ``"network"`` without
        ``analytic``, ``"hybrid"`` with it and a network, ``"analytic"`` with no network.
    name, metadata
        A label and free-form provenance stored in the file.

    Example
    -------
    >>> import torch, matforge.export
    >>> net = torch.nn.Sequential(torch.nn.Linear(6, 32), torch.nn.ReLU(),
    ...                           torch.nn.Linear(32, 3))
    >>> matforge.export.brdf_mlp(net, "my-brdf.json", inputs=["wi", "wo"],
    ...                          output_activation="exp")  # doctest: +SKIP
    """
    layers = _layers_of(module_or_layers, activations)
    ana = None
    if analytic is not None:
        eta = [float(v) for v in _numpy(analytic["eta"]).reshape(-1)]
        ana = {
            "kd": [float(v) for v in _numpy(analytic["kd"]).reshape(-1)],
            "alpha": float(_numpy(analytic["alpha"]).reshape(-1)[0]),
            "eta": eta * 3 if len(eta) == 1 else eta,
        }
    if combine is None:
        combine = "network" if ana is None else ("hybrid" if layers else "analytic")
    doc: dict[str, Any] = {
        "format": BRDF_FORMAT,
        "name": name,
        "inputs": [dict(e) if isinstance(e, Mapping) else e for e in inputs] if layers else [],
        "layers": layers,
        "output": {"combine": combine}
        | ({"activation": _act(output_activation)} if layers else {}),
        "analytic": ana,
        "metadata": dict(metadata or {}),
    }
    return _write(doc, path)


def _act(a: str | Sequence[str]) -> str | list[str]:
    return a if isinstance(a, str) else list(a)


def btf_mlp(
    module_or_layers: Any,
    path: str | os.PathLike[str],
    *,
    textures: Sequence[Any],
    inputs: Sequence[str | Mapping[str, Any]] = ({"type": "texture", "index": 0}, "wi", "wo"),
    activations: str | Sequence[str] | None = None,
    output_activation: str | Sequence[str] = "identity",
    foreshortening: str = "included",
    name: str = "",
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write a neural BTF as ``matforge.mlp-btf/1`` (latent textures inside the file).

    Parameters
    ----------
    module_or_layers, activations, output_activation, name, metadata
        As :func:`brdf_mlp`; the network outputs RGB (3 values).
    textures
        Latent textures, each ``(C, H, W)`` (arrays or tensors), stored as float32 and
        sampled bilinearly and periodically at the patch coordinates ``uv``.
    inputs
        Encodings as :func:`brdf_mlp`'s, plus ``uv`` and ``{"type": "texture", "index":
        k}`` (the ``C`` channels of texture ``k``). ``wi`` is the light, ``wo`` the view.
    foreshortening
        ``"included"``: the network's output is the BTF in the UBO2014 convention of
        ``generate.btf`` (a Lambertian surface gives ``albedo / pi * cos(theta_i)``);
        ``"apply"``: matforge multiplies the output by ``cos(theta_i)``.

    Example
    -------
    >>> import torch, matforge.export
    >>> tex = torch.randn(8, 64, 64)
    >>> net = torch.nn.Sequential(torch.nn.Linear(8 + 6, 32), torch.nn.ReLU(),
    ...                           torch.nn.Linear(32, 3))
    >>> matforge.export.btf_mlp(net, "my-btf.json", textures=[tex])  # doctest: +SKIP
    """
    layers = _layers_of(module_or_layers, activations)
    doc: dict[str, Any] = {
        "format": BTF_FORMAT,
        "name": name,
        "inputs": [dict(e) if isinstance(e, Mapping) else e for e in inputs],
        "layers": layers,
        "output": {"combine": "network", "activation": _act(output_activation)},
        "textures": [texture_entry(_numpy(t).astype(np.float32)) for t in textures],
        "foreshortening": foreshortening,
        "metadata": dict(metadata or {}),
    }
    return _write(doc, path)


__all__ = ["brdf_mlp", "btf_mlp"]
