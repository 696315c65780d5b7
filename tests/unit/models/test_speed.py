"""The speed report's helpers (:mod:`models.speed`): the FLOP count and the CPU-time timer.

Oracle for the FLOP count: the layer sizes by hand (2 per multiply-add of a dense layer).
No timing thresholds: the timer is only checked to run the frozen kernel and report.
"""

from __future__ import annotations

import types

import numpy as np

from models.fused_mlp import DenseLayer, fused_mlp, random_layers
from models.speed import mlp_flops, time_cpu


def test01_mlp_flops() -> None:
    layers = random_layers(np.random.default_rng(0), 10, 32, 3, 6)
    assert mlp_flops(layers) == 2 * (10 * 32 + 2 * 32 * 32 + 32 * 6)
    # The hybrid's MLP: the latent's 4 inputs are folded into the bias.
    assert mlp_flops(layers, 6) == 2 * (6 * 32 + 2 * 32 * 32 + 32 * 6) == 4864
    w = layers[1].weight.copy()
    w[0, :5] = 0.0  # zero weights are skipped by the fused kernel
    layers[1] = DenseLayer(w, layers[1].bias, "relu")
    assert mlp_flops(layers, 6) == 4864 - 10


def test02_time_cpu_runs_the_frozen_kernel(mi: types.ModuleType) -> None:
    layers = random_layers(np.random.default_rng(1), 3, 8, 1, 2)
    xs = [mi.Float(c) for c in np.random.default_rng(2).uniform(-1, 1, (3, 4096))]
    t = time_cpu(lambda *a: fused_mlp(layers, list(a)), xs, repeats=2, launches=2)
    assert set(t) == {"kernel_s", "cpu_s"}
    assert all(np.isfinite(v) and v >= 0.0 for v in t.values())
