"""What the four training examples share: the command line, a tiny MLP and its training
loop (plain torch).

Each example trains on one dataset family, read with ``matforge.datasets`` only::

    python examples/train_merl.py                       # generates a small dataset first
    python examples/train_merl.py --job <id> --data-dir matforge-data
    python examples/train_merl.py --job <id> --server http://127.0.0.1:8000
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset

import matforge


def mlp(n_in: int, n_out: int, width: int = 32, depth: int = 2) -> nn.Sequential:
    """A small ReLU MLP (the kind of model a real-time material network is)."""
    layers: list[nn.Module] = []
    d = n_in
    for _ in range(depth):
        layers += [nn.Linear(d, width), nn.ReLU()]
        d = width
    layers.append(nn.Linear(d, n_out))
    return nn.Sequential(*layers)


def fit(
    net: nn.Module,
    data: Dataset,
    loss_of: Callable[[dict[str, torch.Tensor]], torch.Tensor],
    *,
    steps: int,
    batch: int,
    lr: float,
    shuffle: bool = True,
) -> tuple[float, float]:
    """``steps`` Adam steps at ``lr`` on ``loss_of(b)`` of batches ``b`` of ``data``
    (passes over it, reshuffled each time unless ``shuffle`` is off, until ``steps``);
    returns the mean loss of the first and of the last 20 steps."""
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    losses: list[float] = []
    while len(losses) < steps:
        for b in DataLoader(data, batch_size=batch, shuffle=shuffle):
            loss = loss_of(b)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
            if len(losses) == steps:
                break
    return sum(losses[:20]) / 20, sum(losses[-20:]) / 20


def open_dataset(args: argparse.Namespace, spec: dict[str, Any]) -> Any:
    """The dataset of ``--job`` (from ``--data-dir`` or ``--server``), or of ``spec`` run
    in this process into ``--data-dir``."""
    if args.job and args.server:
        return matforge.datasets.open(args.job, client=matforge.Client(args.server))
    if args.job:
        return matforge.datasets.open(args.job, data_dir=args.data_dir)
    job = matforge.run(spec, data_dir=args.data_dir)
    return matforge.datasets.open(job["id"], data_dir=args.data_dir)


def cli(description: str, spec: dict[str, Any], train: Callable[..., tuple[float, float]]) -> None:
    """Parse the command line, open (or make) the dataset, train, print the losses."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--job", help="a finished dataset job (default: generate one)")
    parser.add_argument("--data-dir", default="matforge-data", help="local data directory")
    parser.add_argument("--server", help="read --job from this server instead")
    parser.add_argument("--steps", type=int, default=300, help="optimiser steps")
    args = parser.parse_args()
    torch.manual_seed(0)
    first, last = train(open_dataset(args, spec), steps=args.steps)
    print(f"loss {first:.4g} -> {last:.4g} in {args.steps} steps")
