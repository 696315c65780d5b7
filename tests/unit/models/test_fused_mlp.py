"""The fused Dr.Jit MLP (:mod:`models.fused_mlp`) against numpy matmuls and torch eager.

Oracle: :func:`models.fused_mlp.mlp_numpy` (``x @ W.T + b`` per layer, float32), which
shares nothing with the unrolled Dr.Jit trace but the activation names; and torch's own
``nn.Sequential`` built by :func:`models.fused_mlp.torch_mlp`.

Tolerances: every side is float32 and sums in its own order (Dr.Jit's unrolled chains and
FMAs, BLAS blocks whose size depends on the CPU, torch's kernels), a few ulps (1.2e-7) of
the terms' magnitude per layer; over 2-3 layers of up to 64 inputs that stays under 1e-5
relative to ``max(|y|, 1)`` (measured at most 7.5e-7 here, AMD EPYC; torch against numpy
used a tenth of its bound). A wrong weight, bias or activation moves outputs by O(0.1).
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from models.fused_mlp import (
    ACTIVATIONS,
    DenseLayer,
    fused_mlp,
    make_layers,
    mlp_numpy,
    parameter_count,
    random_layers,
    torch_mlp,
)


def run_fused(mi: types.ModuleType, layers: list[DenseLayer], x: np.ndarray) -> np.ndarray:
    outs = fused_mlp(layers, [mi.Float(col) for col in x.T])
    return np.stack([np.asarray(o, np.float32) for o in outs], axis=1)


@pytest.mark.parametrize(("width", "depth"), [(16, 2), (32, 3), (64, 2)])
def test01_matches_numpy(mi: types.ModuleType, width: int, depth: int) -> None:
    rng = np.random.default_rng(width * 10 + depth)
    layers = random_layers(rng, 10, width, depth, 6)
    x = rng.uniform(-1.0, 1.0, (4096, 10)).astype(np.float32)
    got, ref = run_fused(mi, layers, x), mlp_numpy(layers, x)
    err = np.abs(got - ref) / np.maximum(np.abs(ref), 1.0)
    print(f"\n{width}x{depth}: max error {err.max():.2e}")
    assert err.max() < 1e-5


@pytest.mark.parametrize("activation", ACTIVATIONS)
def test02_activations(mi: types.ModuleType, activation: str) -> None:
    """Every activation, hidden and last, against numpy (and torch)."""
    rng = np.random.default_rng(1)
    layers = random_layers(rng, 3, 8, 1, 4, hidden=activation, last=activation)
    # Half the He scale keeps exp(W exp(W x)) finite; pre-activations span about [-6, 6].
    layers = [DenseLayer(ly.weight * 0.5, ly.bias, ly.activation) for ly in layers]
    x = rng.uniform(-3.0, 3.0, (2048, 3)).astype(np.float32)
    got, ref = run_fused(mi, layers, x), mlp_numpy(layers, x)
    err = np.abs(got - ref) / np.maximum(np.abs(ref), 1.0)
    assert np.all(np.isfinite(ref)) and err.max() < 1e-5, err.max()
    import torch

    with torch.inference_mode():
        ref_t = torch_mlp(layers)(torch.from_numpy(x)).numpy()
    assert np.allclose(ref_t, ref, rtol=2e-5, atol=1e-6)


def test03_constant_inputs_fold_into_bias(mi: types.ModuleType) -> None:
    """Python-float inputs (a baked latent code) give the same outputs as arrays of them."""
    rng = np.random.default_rng(2)
    layers = random_layers(rng, 7, 16, 2, 3, last="sigmoid")
    z = [0.25, -1.5, 0.75, 2.0]
    x = rng.uniform(-1.0, 1.0, (1000, 3)).astype(np.float32)
    full = np.concatenate([x, np.tile(np.asarray(z, np.float32), (len(x), 1))], axis=1)
    outs = fused_mlp(layers, [*(mi.Float(c) for c in x.T), *z])
    got = np.stack([np.asarray(o) for o in outs], axis=1)
    assert np.allclose(got, mlp_numpy(layers, full), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="at least one input must be a Dr.Jit array"):
        fused_mlp(layers, [0.0] * 7)


def test04_zero_rows_and_checks(mi: types.ModuleType) -> None:
    w = np.array([[0.0, 0.0], [1.0, -2.0]], np.float32)
    layers = make_layers([(w, np.array([0.5, 0.0], np.float32))], ["identity"])
    x = np.array([[1.0, 2.0], [3.0, -1.0]], np.float32)
    assert np.array_equal(run_fused(mi, layers, x), [[0.5, -3.0], [0.5, 5.0]])
    assert parameter_count(layers) == 6
    with pytest.raises(ValueError, match="do not chain"):
        make_layers([(np.ones((4, 3)), np.ones(4)), (np.ones((2, 5)), np.ones(2))], ["relu"] * 2)
    with pytest.raises(ValueError, match="unknown activation"):
        DenseLayer(np.ones((1, 1)), np.ones(1), "gelu")
    with pytest.raises(ValueError, match="finite"):
        DenseLayer(np.full((1, 1), np.nan), np.ones(1), "relu")
    with pytest.raises(ValueError, match="takes 2 inputs"):
        fused_mlp(layers, [mi.Float(1.0)])


@pytest.mark.parametrize("partial_sums", [None, 1, 2, 3])
def test05_chains_zero_weights_and_biases(mi: types.ModuleType, partial_sums: int | None) -> None:
    """Every way an output's sum can start: from the bias, from a product when the bias is
    0, with the bias added last when chain 0's weights are all 0; at every chain count."""
    rng = np.random.default_rng(5)
    layers = random_layers(rng, 7, 40, 2, 3, last="sigmoid")  # 40 wide: 2 chains by default
    w0, b0 = layers[0].weight.copy(), layers[0].bias.copy()
    b0[::3] = 0.0  # outputs whose chain 0 starts with a product
    w0[1, ::2] = 0.0  # chain 0 (even inputs, at 2 chains) all zero, bias added last
    w0[2, ::3] = 0.0  # chain 0 all zero at 3 chains
    w0[4, :] = 0.0  # a constant output
    w1 = layers[1].weight.copy()
    w1[:, :20] = 0.0  # wide layer: its first half of inputs unused
    layers = [
        DenseLayer(w0, b0, "relu"),
        DenseLayer(w1, layers[1].bias, "relu"),
        layers[2],
    ]
    x = rng.uniform(-1.0, 1.0, (512, 7)).astype(np.float32)
    outs = fused_mlp(layers, [mi.Float(c) for c in x.T], partial_sums=partial_sums)
    got = np.stack([np.asarray(o, np.float32) for o in outs], axis=1)
    assert np.allclose(got, mlp_numpy(layers, x), rtol=1e-5, atol=1e-6)


def test06_relu_keeps_nan(mi: types.ModuleType) -> None:
    """ReLU as a select is the numpy ReLU, NaN included (np.maximum propagates NaN)."""
    layers = make_layers([(np.ones((1, 1), np.float32), np.zeros(1, np.float32))], ["relu"])
    x = np.array([[np.nan], [-1.0], [2.0], [-0.0], [np.inf], [-np.inf]], np.float32)
    got, ref = run_fused(mi, layers, x), mlp_numpy(layers, x)
    assert np.isnan(got[0, 0]) and np.isnan(ref[0, 0])
    assert np.array_equal(got[1:], ref[1:])  # -0.0 == 0.0: only a zero's sign may differ
