"""What the four training examples share: the command line and a tiny MLP (plain torch).

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
