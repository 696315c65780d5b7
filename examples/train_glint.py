"""Fit the multi-scale NDF of a glint example: ``(level, uv, s) -> density``.

Data: ``GlintExample.torch_dataset`` (every cell of every NDF level: the tile's centre,
its size, the cell's slope-space centre and the mean P-NDF density there). Loss: squared
error in ``log(1 + density)`` (densities are peaked, glints: most cells are near zero, so
an L1 fit would settle on the median, zero).
"""

from __future__ import annotations

from typing import Any

import torch
from common import cli, fit, mlp

SPEC = {"kind": "generate.glint", "seed": 3,
        "params": {"example": {"procedural": "isotropic_noise", "size": 8},
                   "ndf_resolution": 16}}  # fmt: skip


def train(g: Any, steps: int = 300, batch: int = 512) -> tuple[float, float]:
    """Train; returns the mean loss of the first and of the last 20 steps."""
    data = g.torch_dataset()
    net = mlp(6, 1, width=64)

    def loss(b: dict[str, torch.Tensor]) -> torch.Tensor:
        x = torch.cat([b["uv"], b["footprint"][:, None], b["s"],
                       b["level"][:, None].float()], dim=1)  # fmt: skip
        return ((net(x)[:, 0] - torch.log1p(b["density"])) ** 2).mean()

    return fit(net, data, loss, steps=steps, batch=batch, lr=1e-2)


if __name__ == "__main__":
    cli(__doc__ or "", SPEC, train)
