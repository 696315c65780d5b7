"""Tiny MLPs as fused Dr.Jit kernels: weights unrolled as literals, one MLP per SIMD lane.

Why: a 32x3 MLP run by torch eager on a CPU launches one matmul per layer over the whole
batch and streams every hidden activation through memory. Traced into Dr.Jit instead, with
each weight a *literal* Python float, the network becomes straight-line code inside the
surrounding kernel (a BSDF's ``eval``, or Mitsuba's whole path tracer): every SIMD lane
evaluates its own MLP in registers, and nothing but the inputs and outputs touches memory.
``shared/NOTES.md`` ("Tiny MLPs: where the time goes") measured 5-10x over torch eager;
``benchmarks/bench_fused_mlp.py`` measures this implementation.

Conventions
-----------
- A layer is ``y = act(W x + b)`` with ``W`` of shape ``(out, in)`` and ``b`` of shape
  ``(out,)``, float32: torch's ``nn.Linear`` layout, so ``x @ W.T + b`` in numpy.
- Inputs and outputs of :func:`fused_mlp` are lists of Dr.Jit ``Float`` arrays (one array
  per feature, all the same length), e.g. ``mi.Float`` of the active variant
  (``llvm_ad_rgb`` or ``cuda_ad_rgb``).
  An input may also be a Python ``float``: a per-material constant such as a latent code.
  Constant inputs are folded into the first layer's bias (in float64, then rounded once),
  so a baked latent costs nothing per evaluation.
- Every output is ``b + sum_i W_i x_i``: one chain of fused multiply-adds that starts from
  the bias, or ``ceil(in / MAX_CHAIN)`` interleaved partial chains (:data:`MAX_CHAIN`)
  for wide layers, whose dependency chains would otherwise be too long for the CPU to
  overlap. Each extra chain costs one add per output, so narrow layers use one (measured
  per core, ``BENCHMARKS.md`` "Fused Dr.Jit kernel": at 16x3 and 32x3 one chain is as fast
  as two and faster than four; at 64x3 two are 15 % faster than one). Results differ from
  numpy's float32 matmul only by summation order, ~1e-6 relative.

Nothing here triggers evaluation: the returned arrays are lazy, and the whole MLP is
compiled with whatever consumes them, so kernel compilation happens once per distinct
network (Dr.Jit caches kernels by their IR) and is excluded from per-evaluation timings.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Longest fma chain per output before a layer splits its sums into partial chains (see
#: the module docstring): a layer with ``n`` inputs uses ``ceil(n / MAX_CHAIN)`` chains.
MAX_CHAIN = 32

#: Slope of ``leaky_relu`` for negative inputs (torch's default).
LEAKY_SLOPE = 0.01

#: Activation names understood by :func:`fused_mlp`, :func:`mlp_numpy` and
#: :func:`torch_mlp`.
ACTIVATIONS = ("identity", "relu", "leaky_relu", "sigmoid", "exp", "softplus", "tanh")


@dataclass(frozen=True)
class DenseLayer:
    """One fully connected layer ``y = act(W x + b)``.

    Attributes
    ----------
    weight
        ``(out, in)`` float32 (torch ``nn.Linear.weight`` layout).
    bias
        ``(out,)`` float32.
    activation
        One of :data:`ACTIVATIONS`.
    """

    weight: np.ndarray
    bias: np.ndarray
    activation: str

    def __post_init__(self) -> None:
        w = np.ascontiguousarray(self.weight, dtype=np.float32)
        b = np.ascontiguousarray(self.bias, dtype=np.float32).reshape(-1)
        if w.ndim != 2 or b.shape != (w.shape[0],):
            raise ValueError(
                f"layer shapes must be W (out, in), b (out,); got {w.shape}, {b.shape}"
            )
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(b))):
            raise ValueError("layer weights must be finite")
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"unknown activation {self.activation!r}; known: {ACTIVATIONS}")
        object.__setattr__(self, "weight", w)
        object.__setattr__(self, "bias", b)

    @property
    def n_in(self) -> int:
        """Input features."""
        return int(self.weight.shape[1])

    @property
    def n_out(self) -> int:
        """Output features."""
        return int(self.weight.shape[0])


def make_layers(
    params: Sequence[tuple[np.ndarray, np.ndarray]], activations: Sequence[str]
) -> list[DenseLayer]:
    """Pair ``(W, b)`` arrays with activation names into checked, chained layers."""
    if len(params) != len(activations) or not params:
        raise ValueError("need one activation per (W, b) layer, and at least one layer")
    layers = [DenseLayer(w, b, a) for (w, b), a in zip(params, activations, strict=True)]
    for prev, nxt in zip(layers[:-1], layers[1:], strict=True):
        if prev.n_out != nxt.n_in:
            raise ValueError(f"layer widths do not chain: {prev.n_out} outputs -> {nxt.n_in}")
    return layers


def parameter_count(layers: Sequence[DenseLayer]) -> int:
    """Weights and biases of the network (float32 each, so bytes = 4x this)."""
    return sum(layer.weight.size + layer.bias.size for layer in layers)


def random_layers(
    rng: np.random.Generator,
    n_in: int,
    width: int,
    depth: int,
    n_out: int,
    *,
    hidden: str = "relu",
    last: str = "identity",
) -> list[DenseLayer]:
    """A ``width x depth`` MLP (``depth`` hidden layers) with He-initialised random weights.

    For tests and benchmarks: ``n_in -> width (x depth) -> n_out``, ``hidden`` activation
    after every hidden layer and ``last`` after the output layer.
    """
    dims = [n_in, *([width] * depth), n_out]
    params = [
        (
            rng.normal(0.0, math.sqrt(2.0 / a), (b, a)).astype(np.float32),
            rng.normal(0.0, 0.1, b).astype(np.float32),
        )
        for a, b in zip(dims[:-1], dims[1:], strict=True)
    ]
    return make_layers(params, [hidden] * depth + [last])


# -- numpy reference ---------------------------------------------------------------------


def _numpy_activation(name: str, x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        if name == "identity":
            return x
        if name == "relu":
            return np.maximum(x, 0.0)
        if name == "leaky_relu":
            return np.where(x >= 0.0, x, LEAKY_SLOPE * x)
        if name == "sigmoid":
            return 1.0 / (1.0 + np.exp(-x))
        if name == "exp":
            return np.exp(x)
        if name == "softplus":
            return np.maximum(x, 0.0) + np.log1p(np.exp(-np.abs(x)))
        if name == "tanh":
            return np.tanh(x)
    raise ValueError(f"unknown activation {name!r}")


def mlp_numpy(layers: Sequence[DenseLayer], x: np.ndarray) -> np.ndarray:
    """The reference evaluation: ``(N, in)`` float32 in, ``(N, out)`` float32 out."""
    h = np.asarray(x, dtype=np.float32)
    if h.ndim != 2 or h.shape[1] != layers[0].n_in:
        raise ValueError(f"x must have shape (N, {layers[0].n_in}), got {h.shape}")
    for layer in layers:
        h = _numpy_activation(layer.activation, h @ layer.weight.T + layer.bias)
    return h.astype(np.float32, copy=False)


# -- Dr.Jit ---------------------------------------------------------------------------------


def drjit_activation(dr: Any, name: str) -> Callable[[Any], Any]:
    """The Dr.Jit twin of an activation (``dr`` is the ``drjit`` module).

    ``relu`` is ``select(x < 0, 0, x)`` rather than ``dr.maximum(x, 0)``: the same values
    (NaN stays NaN; only the sign of a zero may differ), but LLVM lowers this select to one
    ``vmaxps`` while ``dr.maximum`` becomes ``llvm.maximum``, which x86 expands to a max, an
    unordered compare and a masked move (see ``BENCHMARKS.md``, "Fused Dr.Jit kernel").
    """
    if name == "identity":
        return lambda x: x
    if name == "relu":
        return lambda x: dr.select(x < 0.0, 0.0, x)
    if name == "leaky_relu":
        return lambda x: dr.select(x >= 0.0, x, x * LEAKY_SLOPE)
    if name == "sigmoid":
        return lambda x: dr.rcp(1.0 + dr.exp(-x))
    if name == "exp":
        return lambda x: dr.exp(x)
    if name == "softplus":
        return lambda x: dr.maximum(x, 0.0) + dr.log(1.0 + dr.exp(-dr.abs(x)))
    if name == "tanh":
        return lambda x: dr.tanh(x)
    raise ValueError(f"unknown activation {name!r}")


def _dense(dr: Any, layer: DenseLayer, xs: Sequence[Any], partial_sums: int) -> list[Any]:
    """One unrolled layer: every output a literal-weighted sum of the Float inputs.

    The first chain starts from the bias (``fma(x, w, b)``), the others from a product; so
    an output costs one FMA per nonzero weight plus ``chains - 1`` adds, and no separate
    bias add.
    """
    w = layer.weight.tolist()  # Python floats: traced as literals, not memory loads
    act = drjit_activation(dr, layer.activation)
    out = []
    for j, row in enumerate(w):
        bias = float(layer.bias[j])
        chains: list[Any] = [None] * partial_sums
        for i, x in enumerate(xs):
            if row[i] == 0.0:
                continue
            k = i % partial_sums
            if chains[k] is not None:
                chains[k] = dr.fma(x, row[i], chains[k])
            elif k == 0 and bias != 0.0:
                chains[k] = dr.fma(x, row[i], bias)
            else:
                chains[k] = x * row[i]
        acc: Any = None
        for chain in chains:
            if chain is not None:
                acc = chain if acc is None else acc + chain
        if acc is None:  # a row of zeros: the output is the constant bias
            acc = dr.zeros(type(xs[0]), dr.width(xs[0])) + bias if xs else bias
        elif chains[0] is None and bias != 0.0:  # the bias had no chain to start
            acc = acc + bias
        out.append(act(acc))
    return out


def _fold_constants(layer: DenseLayer, inputs: Sequence[Any]) -> tuple[DenseLayer, list[Any]]:
    """Move Python-float inputs into the bias: ``b' = b + W[:, const] @ x_const``."""
    const = [i for i, x in enumerate(inputs) if isinstance(x, (int, float))]
    if not const:
        return layer, list(inputs)
    live = [i for i in range(len(inputs)) if i not in const]
    values = np.array([float(inputs[i]) for i in const])
    bias = layer.bias.astype(np.float64) + layer.weight[:, const].astype(np.float64) @ values
    folded = DenseLayer(layer.weight[:, live], bias.astype(np.float32), layer.activation)
    return folded, [inputs[i] for i in live]


def fused_mlp(
    layers: Sequence[DenseLayer],
    inputs: Sequence[Any],
    *,
    partial_sums: int | None = None,
) -> list[Any]:
    """Trace the MLP over Dr.Jit arrays, weights unrolled as literals (lazy, no evaluation).

    Parameters
    ----------
    layers
        The network, e.g. from :func:`make_layers`.
    inputs
        ``layers[0].n_in`` entries, each a Dr.Jit ``Float`` array (all of one type and
        width) or a Python ``float`` constant (folded into the first bias). At least one
        entry must be an array unless the network's output is wanted as constants.
    partial_sums
        Interleaved fma chains per output; ``None`` (the default) picks
        ``ceil(inputs / MAX_CHAIN)`` per layer (see the module docstring).

    Returns
    -------
    ``layers[-1].n_out`` Dr.Jit arrays, unevaluated: they fuse into whatever kernel reads
    them.
    """
    import drjit as dr

    if not layers:
        raise ValueError("an MLP needs at least one layer")
    if len(inputs) != layers[0].n_in:
        raise ValueError(f"the MLP takes {layers[0].n_in} inputs, got {len(inputs)}")
    if partial_sums is not None and partial_sums < 1:
        raise ValueError("partial_sums must be >= 1")
    first, xs = _fold_constants(layers[0], inputs)
    if not xs:
        raise ValueError("at least one input must be a Dr.Jit array")
    h = xs
    for layer in (first, *layers[1:]):
        chains = partial_sums or -(-len(h) // MAX_CHAIN)
        h = _dense(dr, layer, h, chains)
    return h


# -- torch eager (the baseline of the speed benchmarks) ------------------------------------


def torch_mlp(layers: Sequence[DenseLayer]) -> Any:
    """The same network as a float32 ``torch.nn.Sequential`` (for torch-eager timings)."""
    import torch

    class Exp(torch.nn.Module):
        def forward(self, x: Any) -> Any:
            return torch.exp(x)

    acts: dict[str, Callable[[], Any]] = {
        "relu": torch.nn.ReLU,
        "leaky_relu": lambda: torch.nn.LeakyReLU(LEAKY_SLOPE),
        "sigmoid": torch.nn.Sigmoid,
        "exp": Exp,
        "softplus": torch.nn.Softplus,
        "tanh": torch.nn.Tanh,
    }
    modules: list[Any] = []
    for layer in layers:
        linear = torch.nn.Linear(layer.n_in, layer.n_out)
        with torch.no_grad():
            linear.weight.copy_(torch.from_numpy(layer.weight))
            linear.bias.copy_(torch.from_numpy(layer.bias))
        modules.append(linear)
        if layer.activation != "identity":
            modules.append(acts[layer.activation]())
    return torch.nn.Sequential(*modules).eval()
