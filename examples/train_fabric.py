"""Fit the four aggregated fabric components from footprint queries:
``(center, size, wi, wo, material) -> (C_warp, C_weft, S_warp, S_weft)``.

Data: ``FabricQueries.torch_dataset`` (each query with its Monte Carlo standard errors).
Loss: squared error weighted by ``1 / (stderr^2 + eps)`` summed per query, the
inverse-variance weighting that tells noisy estimates from exact ones.
"""

from __future__ import annotations

from typing import Any

import torch
from common import cli, fit, mlp

SPEC = {"kind": "generate.fabric", "seed": 5,
        "params": {"patterns": ["plain"], "texture_sets": 1, "shading_sets": 2,
                   "queries_per_material": 64, "shard_queries": 32, "samples": 64,
                   "map_resolution": 16, "backend": "numpy"}}  # fmt: skip
EPS = 1e-4


def train(fq: Any, steps: int = 300, batch: int = 64) -> tuple[float, float]:
    """Train; returns the mean loss of the first and of the last 20 steps."""
    data = fq.torch_dataset()
    n_mat = len(fq.names)
    net = mlp(9 + n_mat, 4)

    def loss(b: dict[str, torch.Tensor]) -> torch.Tensor:
        onehot = torch.nn.functional.one_hot(b["material"], n_mat).float()
        x = torch.cat([b["center"], b["size"][:, None], b["wi"], b["wo"], onehot], dim=1)
        w = 1.0 / (b["stderr"] ** 2 + EPS)
        return (w * (net(x) - b["value"]) ** 2).mean() * EPS

    return fit(net, data, loss, steps=steps, batch=batch, lr=3e-3)


if __name__ == "__main__":
    cli(__doc__ or "", SPEC, train)
