"""Fit one small MLP to every table of a MERL collection: ``(wi, wo, material) -> RGB``.

Data: ``MerlCollection.torch_dataset`` (cosine-weighted ``(wi, wo)`` pairs per material,
with the tables' values in 1/sr). Loss: L1 of ``log(1 + f cos(theta_i))``, the
log-compressed cosine-weighted BRDF that the hybrid-BRDF paper fits (its values span
orders of magnitude).
"""

from __future__ import annotations

from typing import Any

import torch
from common import cli, fit, mlp

SPEC = {"kind": "generate.merl", "seed": 5,
        "params": {"collection": {"families": {"metal": 1, "paint": 1}}}}  # fmt: skip


def train(coll: Any, steps: int = 300, batch: int = 512) -> tuple[float, float]:
    """Train; returns the mean loss of the first and of the last 20 steps."""
    data = coll.torch_dataset(pairs=4096, seed=0)
    n_mat = len(coll.names)
    net = mlp(6 + n_mat, 3)

    def loss(b: dict[str, torch.Tensor]) -> torch.Tensor:
        onehot = torch.nn.functional.one_hot(b["material"], n_mat).float()
        x = torch.cat([b["wi"], b["wo"], onehot], dim=1)
        target = torch.log1p(b["rgb"].clamp_min(0) * b["wi"][:, 2:3])
        return (net(x) - target).abs().mean()

    return fit(net, data, loss, steps=steps, batch=batch, lr=3e-3)


if __name__ == "__main__":
    cli(__doc__ or "", SPEC, train)
