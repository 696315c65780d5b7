"""Fit a small neural BTF: ``(uv, wi, wo) -> RGB`` over random texels x directions.

Data: ``BtfSlices.torch_dataset`` (texels drawn uniformly over the slices and the texture,
memory-mapped from the shards). ``uv`` goes through a few Fourier features so that the
MLP can follow the texture; loss: L1 in ``log(1 + BTF)``.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from common import cli, fit, mlp

SPEC = {"kind": "generate.btf", "seed": 4,
        "params": {"surface": {"procedural": "wood", "size": 8}, "resolution": 8, "spp": 2,
                   "directions": [[0, 0, 0, 0], [30, 40, 60, 200], [60, 200, 30, 40],
                                  [75, 90, 10, 0]],
                   "shard_slices": 3}}  # fmt: skip
FREQS = 4


def features(uv: torch.Tensor) -> torch.Tensor:
    """``(N, 2)`` texture coordinates to ``(N, 4 FREQS)`` sines and cosines."""
    k = 2.0 ** torch.arange(FREQS) * 2 * math.pi
    a = uv[:, :, None] * k
    return torch.cat([torch.sin(a), torch.cos(a)], dim=2).flatten(1)


def train(btf: Any, steps: int = 300, batch: int = 256) -> tuple[float, float]:
    """Train; returns the mean loss of the first and of the last 20 steps."""
    data = btf.torch_dataset(length=steps * batch, seed=0)
    net = mlp(4 * FREQS + 6, 3, width=64)

    def loss(b: dict[str, torch.Tensor]) -> torch.Tensor:
        x = torch.cat([features(b["uv"]), b["wi"], b["wo"]], dim=1)
        return (net(x) - torch.log1p(b["rgb"])).abs().mean()

    # one pass: the dataset holds steps * batch draws
    return fit(net, data, loss, steps=steps, batch=batch, lr=3e-3, shuffle=False)


if __name__ == "__main__":
    cli(__doc__ or "", SPEC, train)
