"""ONNX graphs that are MLPs, compiled into the fused Dr.Jit kernel of the built-in models.

A user's ONNX BRDF or BTF (signature in ``docs/onnx-models.md``) whose graph is a small
network of per-row operations -- the graphs ``torch.onnx.export`` writes for an
``nn.Sequential`` of ``Linear`` layers and activations, with ``torch.cat`` and column
slices around it (:func:`matforge.export_onnx.brdf_onnx`) -- is *recognised* by
:func:`compile_onnx` and then runs in the same unrolled-literal kernel as the built-in MLPs
and a user's JSON MLP: every ``MatMul`` or ``Gemm`` with constant weights goes through the
dense layer of :mod:`models.fused_mlp` (one fused multiply-add chain per output, weights as
literals, a following ``Add`` of a constant folded into the bias), every other operation is
traced per column around it. The model then renders inside Mitsuba's symbolic path loop
like ``external_mlp`` (no wavefront mode, no host round trips), its runtime is
``drjit-fused``, and the score, ``evaluate.tss`` and cost paths evaluate that same kernel.
Any other graph keeps running in onnxruntime (:mod:`models.external.onnx_model`, runtime
``onnxruntime``); :func:`open_onnx` picks, and :attr:`OnnxMlpMaterial.runtime` says which ran.

What is recognised (everything else is not, and :class:`NotFusable` says which node):

- tensors of shape ``(N, C)`` (the batch and ``C`` columns; ``(N,)`` after a ``Gather`` or
  ``Squeeze`` of one column) and constants (initialisers, ``Constant`` nodes, and
  anything computed from constants only, folded once when the graph is compiled, by
  onnx's reference evaluator);
- ``MatMul`` and ``Gemm`` (``transA = 0``) of a row tensor by a constant matrix, plus an
  optional constant bias; ``Add``, ``Sub``, ``Mul``, ``Div``, ``Max``, ``Min``, ``Pow``
  (constant exponent) between row tensors of the same width (or one of width 1) or with a
  constant broadcast over the columns;
- ``Relu``, ``LeakyRelu`` (any ``alpha``), ``Sigmoid``, ``Tanh``, ``Exp``, ``Log``,
  ``Softplus``, ``Neg``, ``Abs``, ``Sqrt``, ``Reciprocal``, ``Clip`` (constant bounds),
  ``Identity``, ``Cast`` to float32;
- ``Concat``, ``Slice`` (positive steps), ``Split``, ``Gather`` (constant indices) along
  the column axis, and ``Unsqueeze`` / ``Squeeze`` of that axis;
- comparisons (``Greater``, ``Less``, ``GreaterOrEqual``, ``LessOrEqual``, ``Equal``),
  ``Not``, ``And``, ``Or`` and ``Where`` (a horizon mask, ``torch.where``), and ``Cast`` of
  a comparison to float;
- reductions over the columns (``ReduceSum``, ``ReduceMean``, ``ReduceL2``,
  ``ReduceSumSquare``, ``ReduceMax``, ``ReduceMin``), and ``Expand`` to the ``Shape`` of a
  per-row tensor (what ``torch.nn.functional.normalize`` exports).

Semantics are the graph's own: the value is returned as the graph computes it (no clamp,
no horizon mask: the BSDF plugins mask below the horizon as they do for onnxruntime).
A graph that would unroll more than :data:`MAX_UNROLLED` operations per evaluation is not
compiled (onnxruntime runs it), so that no file can make a kernel that takes long to trace
and compile.
Results differ from onnxruntime's float32 ones by summation order and the transcendental
functions' rounding, about 1e-6 relative (``tests/unit/models/external/test_onnx_mlp.py``).

Costs without a clock (:func:`graph_counts`, for any graph, recognised or not): multiply-adds
per evaluation are those of the graph's matrix products (``MatMul``, ``Gemm``: the reduced
dimension times the output's per-row elements, from ONNX shape inference); bytes read per
evaluation are the floating-point constants' bytes (every weight is read once per
evaluation), except that a constant table read through ``Gather`` or ``GridSample`` counts
only what one evaluation reads from it (the gathered elements; four bilinear taps per sample).
"""

from __future__ import annotations

import logging
import math
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from models.fused_mlp import MAX_CHAIN, DenseLayer

if TYPE_CHECKING:
    from models.external.onnx_model import OnnxMaterial

log = logging.getLogger("matforge.models.onnx_mlp")

#: The runtime of a recognised graph (the built-in MLPs' kernel).
RUNTIME = "drjit-fused"
#: The columns of each signature input.
SIGNATURE_WIDTHS = {"wi": 3, "wo": 3, "uv": 2}
#: Operations per evaluation (a dense layer's ``in * out`` multiply-adds, one per column of
#: an elementwise node) that a graph may unroll into the kernel: twice the MLP format's
#: parameter limit (:data:`storage.formats.mlp_model.MAX_NETWORK_PARAMS`); a larger graph
#: runs in onnxruntime, so that no file can make a kernel that takes long to trace and
#: compile.
MAX_UNROLLED = 1 << 17
#: Elements a graph's constant-only nodes may read in all when folded at load (above it,
#: onnxruntime runs the graph).
MAX_FOLDED = 1 << 22


class NotFusable(ValueError):
    """The graph is not one :func:`compile_onnx` can compile (the message names the node)."""


# -- values -------------------------------------------------------------------------------


@dataclass
class _Row:
    """A per-row tensor: ``(N, len(cols))`` (``rank`` 2) or ``(N,)`` (``rank`` 1, one
    column)."""

    cols: list[Any]
    rank: int = 2
    #: Boolean columns (a comparison's result), for ``Where``, ``Not``, ``And``, ``Or`` and
    #: ``Cast`` to float only.
    mask: bool = False


@dataclass
class _Linear:
    """A pending ``x W^T + b`` (``weight`` ``(out, in)`` float64, ``bias`` ``(out,)``): kept
    unevaluated so that a following constant ``Add`` folds into the bias."""

    xs: list[Any]
    weight: np.ndarray
    bias: np.ndarray


@dataclass(frozen=True)
class _Shape:
    """The shape of a per-row tensor (a ``Shape`` node's output), for ``Expand`` only."""

    rank: int
    width: int


_Value = _Row | _Linear | _Shape | np.ndarray


# -- back ends ----------------------------------------------------------------------------


class _Shapes:
    """The back end of compilation: columns are placeholders, nothing is computed; counts
    the operations the kernel would unroll, refused above :data:`MAX_UNROLLED`."""

    def __init__(self, name: str) -> None:
        self.ops = 0
        self.name = name

    def _count(self, n: int) -> None:
        self.ops += n
        if self.ops > MAX_UNROLLED:
            raise NotFusable(
                f"{self.name}: more than {MAX_UNROLLED} operations per evaluation, too many to "
                "unroll into the fused kernel"
            )

    def dense(self, xs: list[Any], weight: np.ndarray, bias: np.ndarray) -> list[Any]:
        self._count(int(weight.size))
        return [None] * weight.shape[0]

    def unary(self, op: str, x: Any, arg: float = 0.0) -> Any:
        self._count(1)
        return None

    def binary(self, op: str, a: Any, b: Any) -> Any:
        self._count(1)
        return None

    def where(self, c: Any, a: Any, b: Any) -> Any:
        self._count(1)
        return None

    def to_float(self, m: Any) -> Any:
        self._count(1)
        return None

    def logical_not(self, m: Any) -> Any:
        self._count(1)
        return None


class _Numpy:
    """float32 numpy columns (the compiled program's reference, tested against
    onnxruntime)."""

    def dense(self, xs: list[Any], weight: np.ndarray, bias: np.ndarray) -> list[Any]:
        x = np.stack([np.asarray(c, np.float32) for c in xs], axis=1)
        y = x @ weight.T.astype(np.float32) + bias.astype(np.float32)
        return list(y.T)

    def unary(self, op: str, x: Any, arg: float = 0.0) -> Any:
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            return _NUMPY_UNARY[op](np.asarray(x, np.float32), arg)

    def binary(self, op: str, a: Any, b: Any) -> Any:
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            if op in _NUMPY_LOGIC:
                return np.asarray(_NUMPY_LOGIC[op](a, b))
            return np.asarray(_NUMPY_BINARY[op](a, b), np.float32)

    def where(self, c: Any, a: Any, b: Any) -> Any:
        return np.asarray(np.where(c, a, b), np.float32)

    def to_float(self, m: Any) -> Any:
        return np.asarray(m, np.float32)

    def logical_not(self, m: Any) -> Any:
        return np.logical_not(m)


_NUMPY_LOGIC: dict[str, Callable[[Any, Any], Any]] = {
    "Greater": np.greater,
    "Less": np.less,
    "GreaterOrEqual": np.greater_equal,
    "LessOrEqual": np.less_equal,
    "Equal": np.equal,
    "And": np.logical_and,
    "Or": np.logical_or,
}

_DRJIT_COMPARE: dict[str, Callable[[Any, Any], Any]] = {
    "Greater": lambda a, b: a > b,
    "Less": lambda a, b: a < b,
    "GreaterOrEqual": lambda a, b: a >= b,
    "LessOrEqual": lambda a, b: a <= b,
    "Equal": lambda a, b: a == b,
}

_NUMPY_UNARY: dict[str, Callable[[np.ndarray, float], np.ndarray]] = {
    "Relu": lambda x, _: np.maximum(x, np.float32(0)),
    "LeakyRelu": lambda x, a: np.where(x >= 0, x, x * np.float32(a)),
    "Sigmoid": lambda x, _: np.float32(1) / (np.float32(1) + np.exp(-x)),
    "Tanh": lambda x, _: np.tanh(x),
    "Exp": lambda x, _: np.exp(x),
    "Log": lambda x, _: np.log(x),
    "Softplus": lambda x, _: np.maximum(x, np.float32(0)) + np.log1p(np.exp(-np.abs(x))),
    "Neg": lambda x, _: -x,
    "Abs": lambda x, _: np.abs(x),
    "Sqrt": lambda x, _: np.sqrt(x),
    "Reciprocal": lambda x, _: np.float32(1) / x,
}
_NUMPY_BINARY: dict[str, Callable[[Any, Any], Any]] = {
    "Add": lambda a, b: a + b,
    "Sub": lambda a, b: a - b,
    "Mul": lambda a, b: a * b,
    "Div": lambda a, b: a / b,
    "Max": np.maximum,
    "Min": np.minimum,
    "Pow": np.power,
}


class _DrJit:
    """Dr.Jit columns: dense layers through :mod:`models.fused_mlp`'s unrolled kernel."""

    def __init__(self, dr: Any) -> None:
        from models.fused_mlp import drjit_activation

        self.dr = dr
        act = {n: drjit_activation(dr, n) for n in ("relu", "sigmoid", "tanh", "exp", "softplus")}
        self._unary: dict[str, Callable[[Any, float], Any]] = {
            "Relu": lambda x, _: act["relu"](x),
            "LeakyRelu": lambda x, a: dr.select(x >= 0.0, x, x * a),
            "Sigmoid": lambda x, _: act["sigmoid"](x),
            "Tanh": lambda x, _: act["tanh"](x),
            "Exp": lambda x, _: act["exp"](x),
            "Log": lambda x, _: dr.log(x),
            "Softplus": lambda x, _: act["softplus"](x),
            "Neg": lambda x, _: -x,
            "Abs": lambda x, _: dr.abs(x),
            "Sqrt": lambda x, _: dr.sqrt(x),
            "Reciprocal": lambda x, _: dr.rcp(x),
        }

    def dense(self, xs: list[Any], weight: np.ndarray, bias: np.ndarray) -> list[Any]:
        from models.fused_mlp import _dense

        layer = DenseLayer(weight.astype(np.float32), bias.astype(np.float32), "identity")
        return _dense(self.dr, layer, xs, -(-len(xs) // MAX_CHAIN))

    def unary(self, op: str, x: Any, arg: float = 0.0) -> Any:
        return self._unary[op](x, arg)

    def binary(self, op: str, a: Any, b: Any) -> Any:
        dr = self.dr
        if op == "Max":
            return dr.maximum(a, b)
        if op == "Min":
            return dr.minimum(a, b)
        if op == "Pow":
            if isinstance(b, float) and b == 2.0:
                return a * a
            if isinstance(b, float) and b == 0.5:
                return dr.sqrt(a)
            return dr.power(a, b)
        if op == "And":
            return a & b
        if op == "Or":
            return a | b
        if op in _DRJIT_COMPARE:  # Dr.Jit's operators give masks
            return _DRJIT_COMPARE[op](a, b)
        return _NUMPY_BINARY[op](a, b)

    def where(self, c: Any, a: Any, b: Any) -> Any:
        if isinstance(c, bool):
            return a if c else b
        return self.dr.select(c, a, b)

    def to_float(self, m: Any) -> Any:
        return self.dr.select(m, 1.0, 0.0)

    def logical_not(self, m: Any) -> Any:
        return ~m


# -- the program --------------------------------------------------------------------------

_UNARY = frozenset(_NUMPY_UNARY)
_BINARY = frozenset(_NUMPY_BINARY)
_FLOAT = 1  # TensorProto.FLOAT


@dataclass(frozen=True)
class _Node:
    op: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    attrs: dict[str, Any]
    label: str


@dataclass(frozen=True)
class OnnxProgram:
    """A recognised graph: its nodes, constants and signature, run by :meth:`run` on numpy
    or Dr.Jit columns (see the module docstring)."""

    kind: str
    inputs: tuple[str, ...]
    output: str
    nodes: tuple[_Node, ...]
    constants: dict[str, np.ndarray] = field(repr=False)
    uses: dict[str, int] = field(repr=False)
    #: The dense layers' shapes ``(in, out)`` in graph order (after bias folding).
    dense_shapes: tuple[tuple[int, int], ...] = ()

    def run(self, backend: Any, feeds: dict[str, list[Any]]) -> list[Any]:
        """The output's 3 columns for input columns ``feeds`` (``name -> columns``)."""
        out, _, _ = _interpret(self, backend, feeds)
        return out


def _attrs(node: Any) -> dict[str, Any]:
    from onnx import helper

    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def _materialise(backend: Any, v: _Value, dense: list[tuple[int, int]] | None) -> _Value:
    if isinstance(v, _Linear):
        if dense is not None:
            dense.append((v.weight.shape[1], v.weight.shape[0]))
        return _Row(backend.dense(v.xs, v.weight, v.bias))
    return v


def _as_columns(c: np.ndarray, width: int, where: str) -> list[float]:
    """A constant broadcast over ``width`` columns of a row tensor: one float per column."""
    a = np.asarray(c, np.float64)
    if a.ndim > 2 or (a.ndim == 2 and a.shape[0] != 1):
        raise NotFusable(f"{where}: a constant of shape {list(a.shape)} varies along the batch")
    flat = a.reshape(-1)
    if flat.size == 1:
        return [float(flat[0])] * width
    if flat.size != width:
        raise NotFusable(f"{where}: a constant of {flat.size} values against {width} columns")
    return [float(x) for x in flat]


def _axis(attrs: dict[str, Any], rank: int, where: str, default: int = 1) -> None:
    axis = int(attrs.get("axis", default))
    if axis not in (rank - 1, -1) or rank != 2:
        raise NotFusable(f"{where}: only the column axis of an (N, C) tensor (axis {axis})")


def _interpret(
    prog: OnnxProgram, backend: Any, feeds: dict[str, list[Any]]
) -> tuple[list[Any], list[tuple[int, int]], dict[str, Any]]:
    env: dict[str, _Value] = {k: np.asarray(v) for k, v in prog.constants.items()}
    folded = 0
    for name in prog.inputs:
        env[name] = _Row(list(feeds[name]))
    dense: list[tuple[int, int]] = []

    def get(name: str, where: str) -> _Value:
        if name not in env:
            raise NotFusable(f"{where}: input '{name}' is not computed before it is used")
        return env[name]

    def row(name: str, where: str, mask: bool = False) -> _Row:
        v = _materialise(backend, get(name, where), dense)
        env[name] = v
        if not isinstance(v, _Row):
            raise NotFusable(f"{where}: expects a per-row tensor for '{name}'")
        if v.mask != mask:
            kind = "a boolean" if mask else "a float"
            raise NotFusable(f"{where}: expects {kind} tensor for '{name}'")
        return v

    for node in prog.nodes:
        where = node.label
        ins = [n for n in node.inputs]
        for n in ins:  # a pending product read twice is computed once
            if n and isinstance(env.get(n), _Linear) and prog.uses.get(n, 0) > 1:
                env[n] = _materialise(backend, env[n], dense)
        vals = [get(n, where) if n else None for n in ins]
        op = node.op
        if all(isinstance(v, np.ndarray) or v is None for v in vals):
            folded += sum(int(np.asarray(v).size) for v in vals if v is not None)
            if folded > MAX_FOLDED:
                raise NotFusable(f"{where}: constants of more than {MAX_FOLDED} elements to fold")
            env.update(_fold_constant(node, vals, where))
            continue
        out: _Value | list[_Value]
        if op in ("MatMul", "Gemm"):
            out = _linear(node, backend, vals, dense, where)
        elif op in _BINARY or op in _NUMPY_LOGIC:
            out = _binary(node, backend, ins, vals, prog, dense, where)
        elif op == "Where":
            out = _where(
                backend, [v if v is None else _materialise(backend, v, dense) for v in vals], where
            )
        elif op == "Not":
            x = row(ins[0], where, mask=True)
            out = _Row([backend.logical_not(c) for c in x.cols], x.rank, True)
        elif op in _UNARY:
            x = row(ins[0], where)
            arg = float(node.attrs.get("alpha", 0.01)) if op == "LeakyRelu" else 0.0
            out = _Row([backend.unary(op, c, arg) for c in x.cols], x.rank)
        elif op in ("Identity", "Cast"):
            if op == "Cast" and int(node.attrs.get("to", 0)) != _FLOAT:
                raise NotFusable(f"{where}: Cast of a row tensor to a type other than float32")
            v = vals[0]
            if op == "Cast" and isinstance(v, _Row) and v.mask:  # a comparison as 0 or 1
                v = _Row([backend.to_float(c) for c in v.cols], v.rank)
            out = v  # type: ignore[assignment]
        elif op == "Clip":
            x = row(ins[0], where)
            lo, hi = (vals[i] if len(vals) > i else None for i in (1, 2))
            if any(b is not None and not isinstance(b, np.ndarray) for b in (lo, hi)):
                raise NotFusable(f"{where}: Clip bounds must be constants")
            cols = x.cols
            if lo is not None:
                cols = [
                    backend.binary("Max", c, float(np.asarray(lo).reshape(-1)[0])) for c in cols
                ]
            if hi is not None:
                cols = [
                    backend.binary("Min", c, float(np.asarray(hi).reshape(-1)[0])) for c in cols
                ]
            out = _Row(cols, x.rank)
        elif op == "Concat":
            rows = [row(n, where) for n in ins]
            _axis(node.attrs, 2, where)
            if any(r.rank != 2 for r in rows):
                raise NotFusable(f"{where}: Concat of tensors that are not (N, C)")
            out = _Row([c for r in rows for c in r.cols])
        elif op == "Slice":
            out = _slice(row(ins[0], where), vals, where)
        elif op == "Split":
            out = _split(node, row(ins[0], where), vals, where)
        elif op == "Gather":
            x = row(ins[0], where)
            _axis(node.attrs, x.rank, where, default=0)
            idx = vals[1]
            if not isinstance(idx, np.ndarray) or idx.ndim > 1:
                raise NotFusable(f"{where}: Gather needs constant scalar or 1-D indices")
            w = len(x.cols)
            if any(not -w <= int(i) < w for i in idx.reshape(-1)):
                raise NotFusable(f"{where}: Gather index out of range of {w} columns")
            picked = [x.cols[int(i) % w] for i in idx.reshape(-1)]
            out = _Row(picked, 1) if idx.ndim == 0 else _Row(picked)
        elif op in ("Unsqueeze", "Squeeze"):
            out = _squeeze(node, row(ins[0], where), vals, where)
        elif op in _REDUCE:
            out = _reduce(node, backend, row(ins[0], where), vals, where)
        elif op == "Shape":
            x = row(ins[0], where)
            if node.attrs.get("start") is not None or node.attrs.get("end") is not None:
                raise NotFusable(f"{where}: Shape with start or end")
            out = _Shape(x.rank, len(x.cols))
        elif op == "Expand":
            x, shape = row(ins[0], where), vals[1]
            if not isinstance(shape, _Shape) or shape.rank != x.rank:
                raise NotFusable(f"{where}: Expand other than to the shape of a per-row tensor")
            if len(x.cols) not in (1, shape.width):
                raise NotFusable(f"{where}: Expand of {len(x.cols)} columns to {shape.width}")
            out = _Row(x.cols * (shape.width // len(x.cols)), x.rank)
        else:
            raise NotFusable(f"{where}: operator {op} on a per-row tensor")
        outs = out if isinstance(out, list) else [out]
        for name, v in zip(node.outputs, outs, strict=True):
            env[name] = v
    final = row(prog.output, "output")
    if len(final.cols) != 3 or final.rank != 2:
        raise NotFusable(f"output '{prog.output}' has {len(final.cols)} columns, not 3")
    return final.cols, dense, env


_REDUCE = frozenset({"ReduceSum", "ReduceMean", "ReduceL2", "ReduceSumSquare", "ReduceMax",
                     "ReduceMin"})  # fmt: skip


def _reduce(node: _Node, backend: Any, x: _Row, vals: list[Any], where: str) -> _Row:
    """A reduction over the columns of an ``(N, C)`` tensor (``axes`` ``[1]`` or ``[-1]``,
    an attribute or, from opset 18 and for ``ReduceSum`` from 13, an input)."""
    if len(vals) > 1 and vals[1] is not None:
        axes = _ints(vals[1], where)
    else:
        axes = [int(a) for a in node.attrs.get("axes", [])]
    if x.rank != 2 or axes not in ([1], [-1]):
        raise NotFusable(f"{where}: {node.op} other than over the columns of an (N, C) tensor")
    op, cols = node.op, x.cols
    if op in ("ReduceL2", "ReduceSumSquare"):
        cols = [backend.binary("Mul", c, c) for c in cols]
    pick = {"ReduceMax": "Max", "ReduceMin": "Min"}.get(op, "Add")
    acc = cols[0]
    for c in cols[1:]:
        acc = backend.binary(pick, acc, c)
    if op == "ReduceMean":
        acc = backend.binary("Mul", acc, 1.0 / len(cols))
    elif op == "ReduceL2":
        acc = backend.unary("Sqrt", acc)
    return _Row([acc], 2 if int(node.attrs.get("keepdims", 1)) else 1)


def _fold_constant(node: _Node, vals: list[Any], where: str) -> dict[str, np.ndarray]:
    """A node of constants only, computed now with onnx's reference evaluator."""
    if node.op == "Constant":
        from onnx import numpy_helper

        if "value" in node.attrs:
            return {node.outputs[0]: numpy_helper.to_array(node.attrs["value"])}
        for key in ("value_float", "value_int"):
            if key in node.attrs:
                return {node.outputs[0]: np.asarray(node.attrs[key])}
        for key in ("value_floats", "value_ints"):
            if key in node.attrs:
                return {node.outputs[0]: np.asarray(list(node.attrs[key]))}
        raise NotFusable(f"{where}: a Constant of an unsupported value")
    from onnx import helper
    from onnx.reference import ReferenceEvaluator

    inputs = [f"i{k}" if v is not None else "" for k, v in enumerate(vals)]
    attrs = dict(node.attrs)
    one = helper.make_node(node.op, inputs, [f"o{k}" for k in range(len(node.outputs))], **attrs)
    try:
        run = ReferenceEvaluator(one)
        res = run.run(None, {f"i{k}": v for k, v in enumerate(vals) if v is not None})
    except Exception as exc:  # an operator the reference evaluator lacks or refuses
        raise NotFusable(f"{where}: cannot fold {node.op} of constants ({exc})") from None
    return {n: np.asarray(r) for n, r in zip(node.outputs, res, strict=True)}


def _linear(
    node: _Node, backend: Any, vals: list[Any], dense: list[tuple[int, int]], where: str
) -> _Linear:
    a, b = vals[0], vals[1]
    c = vals[2] if len(vals) > 2 else None
    if not isinstance(b, np.ndarray) or b.ndim != 2:
        raise NotFusable(f"{where}: {node.op} by a matrix that is not a constant (K, M)")
    x = _materialise(backend, a, dense)
    if not isinstance(x, _Row) or x.rank != 2:
        raise NotFusable(f"{where}: {node.op} of a tensor that is not (N, K)")
    w = np.asarray(b, np.float64)
    bias = np.zeros(0)
    if node.op == "Gemm":
        if int(node.attrs.get("transA", 0)):
            raise NotFusable(f"{where}: Gemm with transA")
        w = w.T if int(node.attrs.get("transB", 0)) else w
        w = w * float(node.attrs.get("alpha", 1.0))
        if c is not None:
            if not isinstance(c, np.ndarray):
                raise NotFusable(f"{where}: Gemm's C is not a constant")
            bias = float(node.attrs.get("beta", 1.0)) * np.asarray(
                _as_columns(c, w.shape[1], where)
            )
    if w.shape[0] != len(x.cols):
        raise NotFusable(f"{where}: {node.op} of {len(x.cols)} columns by a {list(w.shape)} matrix")
    weight = np.ascontiguousarray(w.T)  # (out, in)
    if bias.size == 0:
        bias = np.zeros(weight.shape[0])
    return _Linear(list(x.cols), weight, bias)


def _binary(
    node: _Node,
    backend: Any,
    ins: list[str],
    vals: list[Any],
    prog: OnnxProgram,
    dense: list[tuple[int, int]],
    where: str,
) -> _Value:
    op = node.op
    if len(vals) != 2:
        raise NotFusable(f"{where}: {op} of {len(vals)} inputs")
    a, b = vals
    # x W^T + b: a constant added to a pending product that nothing else reads joins its bias.
    if op in ("Add", "Sub") and isinstance(b, np.ndarray) and isinstance(a, _Linear):
        if prog.uses.get(ins[0], 0) == 1:
            c = np.asarray(_as_columns(b, a.weight.shape[0], where))
            return _Linear(a.xs, a.weight, a.bias + (c if op == "Add" else -c))
    if op == "Add" and isinstance(a, np.ndarray) and isinstance(b, _Linear):
        if prog.uses.get(ins[1], 0) == 1:
            c = np.asarray(_as_columns(a, b.weight.shape[0], where))
            return _Linear(b.xs, b.weight, b.bias + c)
    ra = _materialise(backend, a, dense)
    rb = _materialise(backend, b, dense)
    logic = op in _NUMPY_LOGIC
    for v in (ra, rb):
        if not isinstance(v, _Row | np.ndarray):
            raise NotFusable(f"{where}: {op} of a tensor that is not per row or constant")
        masked = isinstance(v, _Row) and v.mask
        if masked != (op in ("And", "Or")) or (op in ("And", "Or") and not isinstance(v, _Row)):
            raise NotFusable(f"{where}: {op} of {'a boolean' if masked else 'this'} tensor")
    if op == "Pow" and isinstance(rb, np.ndarray) and np.asarray(rb).size != 1:
        raise NotFusable(f"{where}: Pow with a per-column exponent")
    xs, ys, rank = _pair(ra, rb, op, where)
    return _Row([backend.binary(op, x, y) for x, y in zip(xs, ys, strict=True)], rank, logic)


def _pair(a: _Value, b: _Value, op: str, where: str) -> tuple[list[Any], list[Any], int]:
    """The columns of ``a`` and ``b`` (per-row tensors or constants, one of them per row)
    broadcast against each other, and the result's rank."""
    a, b = _widen(a, b), _widen(b, a)
    if isinstance(a, np.ndarray):
        assert isinstance(b, _Row)
        ca = _as_columns(a, len(b.cols), where) if b.rank == 2 else _scalar(a, where)
        return ca, b.cols, b.rank
    assert isinstance(a, _Row)
    if isinstance(b, np.ndarray):
        cb = _as_columns(b, len(a.cols), where) if a.rank == 2 else _scalar(b, where)
        return a.cols, cb, a.rank
    assert isinstance(b, _Row)
    if a.rank != b.rank:
        raise NotFusable(f"{where}: {op} of an (N,) and an (N, C) tensor")
    wa, wb = len(a.cols), len(b.cols)
    if wa != wb and 1 not in (wa, wb):
        raise NotFusable(f"{where}: {op} of {wa} and {wb} columns")
    n = max(wa, wb)
    return (a.cols * n if wa == 1 else a.cols), (b.cols * n if wb == 1 else b.cols), a.rank


def _where(backend: Any, vals: list[Any], where: str) -> _Row:
    """``Where(cond, a, b)``: a boolean per-row condition (or a constant one) choosing
    between per-row tensors or constants, broadcast as the other binary operations."""
    if len(vals) != 3:
        raise NotFusable(f"{where}: Where of {len(vals)} inputs")
    c, a, b = vals
    for v in (c, a, b):
        if not isinstance(v, _Row | np.ndarray):
            raise NotFusable(f"{where}: Where of a tensor that is not per row or constant")
    if not ((isinstance(c, _Row) and c.mask) or isinstance(c, np.ndarray)):
        raise NotFusable(f"{where}: Where's condition is not a comparison's result")
    if isinstance(a, _Row) and a.mask or isinstance(b, _Row) and b.mask:
        raise NotFusable(f"{where}: Where between boolean tensors")
    rows = [v for v in (c, a, b) if isinstance(v, _Row)]
    rank = rows[0].rank
    if any(r.rank != rank for r in rows):
        raise NotFusable(f"{where}: Where of (N,) and (N, C) tensors")
    n = max(len(r.cols) for r in rows)
    if rank == 2:
        n = max([n] + [int(np.asarray(v).size) for v in (c, a, b) if isinstance(v, np.ndarray)])

    def columns(v: Any) -> list[Any]:
        if isinstance(v, _Row):
            if len(v.cols) not in (1, n):
                raise NotFusable(f"{where}: Where of {len(v.cols)} columns against {n}")
            return v.cols * n if len(v.cols) == 1 else v.cols
        cols = _as_columns(v, n, where) if rank == 2 else _scalar(v, where) * n
        return cols

    cs, xs, ys = columns(c), columns(a), columns(b)
    if isinstance(c, np.ndarray):
        cs = [bool(v) for v in cs]
    return _Row([backend.where(ci, x, y) for ci, x, y in zip(cs, xs, ys, strict=True)], rank)


def _widen(x: _Value, other: _Value) -> _Value:
    """A one-column ``(N, 1)`` row broadcast to the width of a ``(1, C)`` constant."""
    if isinstance(x, _Row) and x.rank == 2 and len(x.cols) == 1 and isinstance(other, np.ndarray):
        size = int(np.asarray(other).size)
        if size > 1 and np.asarray(other).ndim <= 2:
            return _Row(x.cols * size)
    return x


def _scalar(c: np.ndarray, where: str) -> list[float]:
    if np.asarray(c).size != 1:
        raise NotFusable(f"{where}: a constant of shape {list(np.shape(c))} against an (N,) tensor")
    return [float(np.asarray(c).reshape(-1)[0])]


def _ints(v: Any, where: str) -> list[int]:
    if not isinstance(v, np.ndarray):
        raise NotFusable(f"{where}: indices must be constants")
    return [int(x) for x in v.reshape(-1)]


def _slice(x: _Row, vals: list[Any], where: str) -> _Row:
    starts, ends = _ints(vals[1], where), _ints(vals[2], where)
    axes = (
        _ints(vals[3], where) if len(vals) > 3 and vals[3] is not None else list(range(len(starts)))
    )
    steps = _ints(vals[4], where) if len(vals) > 4 and vals[4] is not None else [1] * len(starts)
    cols = x.cols
    for s, e, ax, st in zip(starts, ends, axes, steps, strict=True):
        if st <= 0:
            raise NotFusable(f"{where}: Slice with a step of {st}")
        if ax in (0, -x.rank):
            if s == 0 and e >= 2**31 - 1 and st == 1:
                continue  # the whole batch
            raise NotFusable(f"{where}: Slice along the batch axis")
        if x.rank != 2:
            raise NotFusable(f"{where}: Slice of an (N,) tensor")
        cols = cols[slice(s, e, st)]
    if not cols:
        raise NotFusable(f"{where}: Slice to no columns")
    return _Row(cols, x.rank)


def _split(node: _Node, x: _Row, vals: list[Any], where: str) -> list[_Value]:
    _axis(node.attrs, x.rank, where, default=0)
    k = len(node.outputs)
    w = len(x.cols)
    if len(vals) > 1 and vals[1] is not None:
        sizes = _ints(vals[1], where)
    elif "split" in node.attrs:
        sizes = [int(s) for s in node.attrs["split"]]
    else:
        if w % k:
            raise NotFusable(f"{where}: Split of {w} columns into {k} equal parts")
        sizes = [w // k] * k
    if sum(sizes) != w or len(sizes) != k:
        raise NotFusable(f"{where}: Split sizes {sizes} of {w} columns")
    out: list[_Value] = []
    lo = 0
    for s in sizes:
        out.append(_Row(x.cols[lo : lo + s]))
        lo += s
    return out


def _squeeze(node: _Node, x: _Row, vals: list[Any], where: str) -> _Row:
    if len(vals) > 1 and vals[1] is not None:
        axes = _ints(vals[1], where)
    else:
        axes = [int(a) for a in node.attrs.get("axes", [])]
    if node.op == "Unsqueeze":
        if x.rank != 1 or axes not in ([1], [-1]):
            raise NotFusable(f"{where}: Unsqueeze other than (N,) -> (N, 1)")
        return _Row(x.cols, 2)
    if x.rank != 2 or len(x.cols) != 1 or axes not in ([1], [-1]):
        raise NotFusable(f"{where}: Squeeze other than (N, 1) -> (N,)")
    return _Row(x.cols, 1)


def compile_onnx(model: Any, kind: str, name: str = "model.onnx") -> OnnxProgram:
    """The program of a checked ``onnx.ModelProto`` (``storage.formats.onnx``'s checks
    passed) of ``kind``; :class:`NotFusable` naming the first node it cannot compile."""
    from onnx import numpy_helper

    graph = model.graph
    constants = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    inputs = tuple(vi.name for vi in graph.input if vi.name not in constants)
    uses: dict[str, int] = {}
    nodes = []
    for k, n in enumerate(graph.node):
        for i in n.input:
            uses[i] = uses.get(i, 0) + 1
        label = f"{name}: node '{n.name or n.op_type}' ({n.op_type}, #{k})"
        nodes.append(_Node(n.op_type, tuple(n.input), tuple(n.output), _attrs(n), label))
    output = graph.output[0].name
    uses[output] = uses.get(output, 0) + 1
    prog = OnnxProgram(kind, inputs, output, tuple(nodes), constants, uses)
    feeds = {n: [None] * SIGNATURE_WIDTHS[n] for n in inputs}
    try:
        _, dense, env = _interpret(prog, _Shapes(name), feeds)
    except NotFusable:
        raise
    except (IndexError, KeyError, TypeError, ValueError, AssertionError, AttributeError) as exc:
        # A node of another arity or form than the compiler reads (a graph onnx.checker
        # would refuse, or a form not handled): not compiled, named.
        problem = f"{type(exc).__name__}: {exc}"
        raise NotFusable(f"{name}: the graph does not compile ({problem})") from None
    # Constant-only nodes are folded once, here: the program keeps their values, not them.
    folded = {k: v for k, v in env.items() if isinstance(v, np.ndarray)}
    live = tuple(n for n in nodes if not all(o in folded for o in n.outputs))
    return OnnxProgram(kind, inputs, output, live, folded, uses, tuple(dense))


# -- counts without a clock ---------------------------------------------------------------


def _float_bytes(a: np.ndarray) -> int:
    return int(a.nbytes) if np.issubdtype(a.dtype, np.floating) else 0


def graph_counts(model: Any) -> dict[str, int | None]:
    """``{"macs_per_eval", "bytes_per_eval"}`` of an ``onnx.ModelProto`` (module docstring):
    from its nodes and the shapes ONNX shape inference gives them; ``macs_per_eval`` is
    ``None`` when a product's shapes cannot be inferred."""
    import onnx
    from onnx import numpy_helper

    try:
        inferred = onnx.shape_inference.infer_shapes(model, strict_mode=False, data_prop=True)
    except Exception:  # shape inference is best effort; the checker ran before
        inferred = model
    graph = inferred.graph
    shapes: dict[str, list[Any]] = {}
    for vi in (*graph.input, *graph.value_info, *graph.output):
        tt = vi.type.tensor_type
        shapes[vi.name] = [
            d.dim_value if d.HasField("dim_value") else d.dim_param or None for d in tt.shape.dim
        ]
    tensors: dict[str, np.ndarray] = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    for n in graph.node:
        for a in n.attribute:
            if a.HasField("t") and n.op_type == "Constant":
                tensors[n.output[0]] = numpy_helper.to_array(a.t)
    for name, arr in tensors.items():
        shapes.setdefault(name, list(arr.shape))

    def per_row(dims: list[Any] | None) -> int | None:
        """Elements per evaluation of a tensor whose first dimension is the batch."""
        if not dims or any(not isinstance(d, int) for d in dims[1:]) or isinstance(dims[0], int):
            return None
        return math.prod(dims[1:])

    macs: int | None = 0
    table_reads: dict[str, int] = {}
    for n in graph.node:
        if n.op_type in ("MatMul", "Gemm"):
            a = shapes.get(n.input[0])
            out = per_row(shapes.get(n.output[0]))
            if macs is None or not a or out is None:
                macs = None
                continue
            k = (
                a[0]
                if n.op_type == "Gemm" and any(x.name == "transA" and x.i for x in n.attribute)
                else a[-1]
            )
            macs = None if not isinstance(k, int) else macs + k * out
        if n.op_type in ("Gather", "GridSample") and n.input[0] in tensors:
            out = per_row(shapes.get(n.output[0]))
            item = tensors[n.input[0]].dtype.itemsize
            taps = 4 if n.op_type == "GridSample" else 1
            prev = table_reads.get(n.input[0], 0)
            table_reads[n.input[0]] = prev + (taps * out * item if out is not None else 0)
    read = 0
    for name, arr in tensors.items():
        if name in table_reads:
            read += min(table_reads[name], _float_bytes(arr)) if _float_bytes(arr) else 0
        else:
            read += _float_bytes(arr)
    return {"macs_per_eval": macs, "bytes_per_eval": read}


# -- the material -------------------------------------------------------------------------


@dataclass
class OnnxMlpMaterial:
    """A recognised ONNX BRDF or BTF, evaluated in the fused Dr.Jit kernel.

    Attributes: ``kind``, ``name`` (the file's name), ``program`` (:class:`OnnxProgram`),
    ``param_bytes`` (the floating-point initialisers' bytes, as
    :class:`~models.external.onnx_model.OnnxMaterial`'s), ``macs_per_eval`` and
    ``bytes_per_eval`` (:func:`graph_counts`), ``runtime`` (``"drjit-fused"``).
    """

    kind: str
    name: str
    program: OnnxProgram = field(repr=False)
    param_bytes: int
    macs_per_eval: int | None = None
    bytes_per_eval: int | None = None
    runtime: str = RUNTIME

    def fused(self, mi: types.ModuleType) -> FusedOnnx:
        """The kernel for Mitsuba variant ``mi``."""
        return FusedOnnx(self, mi)

    def eval_numpy(
        self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None
    ) -> np.ndarray:
        """The program on numpy float32 columns (the kernel's reference): ``(N, 3)``."""
        feeds = _feeds(self.kind, wi, wo, uv, self.name)
        cols = self.program.run(_Numpy(), {k: list(v.T) for k, v in feeds.items()})
        n = len(feeds["wi"])
        return np.stack([np.broadcast_to(np.asarray(c, np.float32), (n,)) for c in cols], 1)

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """The model at ``N`` direction pairs, evaluated by the fused kernel: ``(N, 3)``
        float32 (shapes as :meth:`OnnxMaterial.eval`; values as the graph computes them)."""
        from materials.backend import load_mitsuba

        mi = load_mitsuba()
        import drjit as dr

        feeds = _feeds(self.kind, wi, wo, uv, self.name)
        n = len(feeds["wi"])
        arrays = {k: [mi.Float(np.ascontiguousarray(c)) for c in v.T] for k, v in feeds.items()}
        cols = self.program.run(_DrJit(dr), arrays)
        dr.eval(*[c for c in cols if not isinstance(c, float)])
        out = np.empty((n, 3), np.float32)
        for j, c in enumerate(cols):
            out[:, j] = c if isinstance(c, float) else np.asarray(c.numpy(), np.float32)
        return out


def _feeds(
    kind: str, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None, name: str
) -> dict[str, np.ndarray]:
    wi = np.ascontiguousarray(wi, np.float32)
    wo = np.ascontiguousarray(wo, np.float32)
    n = len(wi)
    if wi.shape != (n, 3) or wo.shape != (n, 3):
        raise ValueError(f"wi and wo must be (N, 3), got {wi.shape} and {wo.shape}")
    feeds = {"wi": wi, "wo": wo}
    if kind == "btf":
        if uv is None:
            raise ValueError(f"{name}: a BTF model needs uv (N, 2)")
        uv = np.ascontiguousarray(uv, np.float32)
        if uv.shape != (n, 2):
            raise ValueError(f"uv must be (N, 2), got {uv.shape}")
        feeds["uv"] = uv
    elif uv is not None:
        raise ValueError(f"{name}: a BRDF model takes no uv")
    return feeds


class FusedOnnx:
    """A recognised graph ready to be traced into a Dr.Jit kernel (Mitsuba variant ``mi``):
    the twin of :class:`models.external.fused.FusedMlp` for ONNX files."""

    def __init__(self, material: OnnxMlpMaterial, mi: types.ModuleType) -> None:
        import drjit as dr

        self.material = material
        self.mi, self.dr = mi, dr
        self.backend = _DrJit(dr)

    def eval(self, wi: Any, wo: Any, uv: Any = None) -> Any:
        """The model (``mi.Color3f``, lazy) at ``mi.Vector3f`` directions ``wi``, ``wo``
        (and ``mi.Point2f`` ``uv`` for a BTF), as the graph computes it."""
        mi = self.mi
        feeds: dict[str, list[Any]] = {"wi": [wi[0], wi[1], wi[2]], "wo": [wo[0], wo[1], wo[2]]}
        if self.material.kind == "btf":
            if uv is None:
                raise ValueError(f"{self.material.name}: a BTF is evaluated at uv")
            feeds["uv"] = [uv[0], uv[1]]
        cols = self.material.program.run(self.backend, feeds)
        like = feeds["wi"][0]
        cols = [like * 0.0 + c if isinstance(c, float) else c for c in cols]
        return mi.Color3f(*cols)


# -- opening a file -----------------------------------------------------------------------


def open_onnx(
    path: Path,
    kind: str,
    *,
    threads: int | None = None,
    runtime: str = "auto",
    label: str | None = None,
) -> OnnxMlpMaterial | OnnxMaterial:
    """The ONNX model in ``path`` as a ``kind`` model: an :class:`OnnxMlpMaterial` (fused
    Dr.Jit kernel) when its graph is recognised and ``runtime`` is ``"auto"``, else an
    :class:`~models.external.onnx_model.OnnxMaterial` (onnxruntime, ``threads`` intra-op
    threads). Both carry ``macs_per_eval`` and ``bytes_per_eval`` (:func:`graph_counts`).
    ``label`` names the model in messages (the user's ``sha256:`` or ``job:`` ref; default
    the file's name).

    Raises as :func:`models.external.onnx_model.load_onnx`; ``ValueError`` for a
    ``runtime`` other than ``"auto"`` or ``"onnxruntime"``.
    """
    from models.external.onnx_model import DEFAULT_THREADS, _param_bytes, load_onnx
    from storage.formats.onnx import check_onnx_file, load_onnx_proto

    if runtime not in ("auto", "onnxruntime"):
        raise ValueError(f"runtime must be 'auto' or 'onnxruntime', not {runtime!r}")
    path = Path(path)
    name = label or path.name
    check_onnx_file(path, name, kind)
    proto = load_onnx_proto(path, name)
    counts = graph_counts(proto)
    if runtime == "auto":
        try:
            program = compile_onnx(proto, kind, name)
        except NotFusable as exc:
            log.info("%s runs in onnxruntime: %s", name, exc)
        except Exception:  # a graph the compiler mishandles still runs, in onnxruntime
            log.warning("%s: compiling the graph failed; it runs in onnxruntime", name,
                        exc_info=True)  # fmt: skip
        else:
            return OnnxMlpMaterial(
                kind=kind,
                name=name,
                program=program,
                param_bytes=_param_bytes(proto),
                macs_per_eval=counts["macs_per_eval"],
                bytes_per_eval=counts["bytes_per_eval"],
            )
    model = load_onnx(
        path, kind, threads=DEFAULT_THREADS if threads is None else threads, label=label
    )
    model.macs_per_eval = counts["macs_per_eval"]
    model.bytes_per_eval = counts["bytes_per_eval"]
    return model
