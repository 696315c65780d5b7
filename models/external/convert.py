"""One material of a ``train.brdf`` model (``matforge.brdf-model/1``) as a
``matforge.mlp-brdf/1`` document.

The identity behind it: the hybrid model's ``f = exp(y[0:3]) + sigmoid(y[3:6]) f_a`` with
``y = MLP([wi, wo, z])`` (hidden ReLU, linear last layer) is the MLP format's ``combine:
"hybrid"`` with inputs ``wi, wo``, output activations ``exp`` x 3 and ``sigmoid`` x 3, and the
material's constant latent ``z`` folded into the first bias (``b' = b + W_z z`` in float64);
the analytic model is ``combine: "analytic"``. The neural model's learned frames are folded
into its first layer by :func:`models.brdf.fused.bake_material`, so it is ``combine:
"network"`` with ``exp``. ``tests/unit/models/external/test_mlp.py`` checks the identity
against :func:`models.brdf.portable.eval_portable`; ``benchmarks/bench_external_mlp.py``
times the two kernels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from models.brdf.fused import bake_material
from storage.formats.mlp_model import BRDF_FORMAT


def brdf_material_as_mlp(doc: dict[str, Any], material: str) -> dict[str, Any]:
    """The ``matforge.mlp-brdf/1`` document of material ``material`` of a
    ``matforge.brdf-model/1`` document ``doc``; ``ValueError`` as
    :func:`~models.brdf.fused.bake_material`."""
    baked = bake_material(doc, material)
    layers: list[dict[str, Any]] = []
    for k, ly in enumerate(baked.layers):
        w = ly.weight.astype(np.float64)
        b = ly.bias.astype(np.float64)
        if k == 0:
            b = b + w[:, 6:] @ np.asarray(baked.z, np.float64)
            w = w[:, :6]
        act = "relu" if k < len(baked.layers) - 1 else "identity"
        layers.append({"weight": w.tolist(), "bias": b.tolist(), "activation": act})
    analytic = None
    if baked.has_analytic:
        analytic = {"kd": list(baked.kd or ()), "alpha": baked.alpha, "eta": list(baked.eta or ())}
    combine = {"hybrid": "hybrid", "neural": "network", "analytic": "analytic"}[baked.model]
    output: dict[str, Any] = {"combine": combine}
    if baked.model == "hybrid":
        output["activation"] = ["exp"] * 3 + ["sigmoid"] * 3
    elif baked.model == "neural":
        output["activation"] = "exp"
    return {
        "format": BRDF_FORMAT,
        "name": material,
        "inputs": ["wi", "wo"] if layers else [],
        "layers": layers,
        "output": output,
        "analytic": analytic,
        "metadata": {"from": "matforge.brdf-model/1", "model": baked.model},
    }
