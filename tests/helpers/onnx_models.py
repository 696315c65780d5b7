"""Small ONNX material models for tests, written with ``onnx.helper`` (not with matforge's
export code), and ways to break them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

#: The albedo of the Lambertian test models.
ALBEDO = (0.2, 0.5, 0.8)


def _io(kind: str, batch: str | int = "N") -> tuple[list[onnx.ValueInfoProto], onnx.ValueInfoProto]:
    dims = {"uv": 2, "wi": 3, "wo": 3}
    names = ("uv", "wi", "wo") if kind == "btf" else ("wi", "wo")
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [batch, dims[n]]) for n in names]
    return inputs, helper.make_tensor_value_info("rgb", TensorProto.FLOAT, [batch, 3])


def lambert_model(
    kind: str = "btf",
    albedo: tuple[float, float, float] = ALBEDO,
    opset: int = 17,
    *,
    opaque: bool = True,
) -> onnx.ModelProto:
    """A Lambertian ``kind`` model: BTF ``rgb = albedo / pi * wi.z`` (UBO2014's convention,
    foreshortening of the light ``wi`` included), BRDF ``rgb = albedo / pi`` (no cosine).

    ``opaque`` (the default) ends the graph in a ``Reshape`` to ``[-1, 3]``, an operator the
    fused compiler (:mod:`models.external.onnx_mlp`) does not recognise, so the model runs
    in onnxruntime; ``opaque=False`` leaves the plain graph, which it compiles."""
    inputs, out = _io(kind)
    k = numpy_helper.from_array((np.asarray(albedo, np.float32) / np.float32(np.pi))[None], "k")
    if kind == "btf":
        inits = [
            numpy_helper.from_array(np.array([2], np.int64), "z0"),
            numpy_helper.from_array(np.array([3], np.int64), "z1"),
            numpy_helper.from_array(np.array([1], np.int64), "axis"),
            k,
        ]
        nodes = [
            helper.make_node("Slice", ["wi", "z0", "z1", "axis"], ["cos_i"]),
            helper.make_node("Mul", ["cos_i", "k"], ["rgb"]),
        ]
    else:
        # rgb = albedo / pi for every row: wi * 0 + k, reduced over nothing.
        zero = numpy_helper.from_array(np.zeros((3, 3), np.float32), "zero")
        inits = [k, zero]
        nodes = [
            helper.make_node("MatMul", ["wi", "zero"], ["zeros"]),
            helper.make_node("Add", ["zeros", "k"], ["rgb"]),
        ]
    if opaque:
        nodes[-1].output[0] = "rgb_flat"
        inits.append(numpy_helper.from_array(np.array([-1, 3], np.int64), "rgb_shape"))
        nodes.append(helper.make_node("Reshape", ["rgb_flat", "rgb_shape"], ["rgb"]))
    graph = helper.make_graph(nodes, f"lambert_{kind}", inputs, [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])


def save(model: onnx.ModelProto, path: Path) -> Path:
    """Write ``model`` to ``path`` (embedded tensors) and return ``path``."""
    path.write_bytes(model.SerializeToString())
    return path


def _brdf_model(
    nodes: list[onnx.NodeProto], inits: list[onnx.TensorProto], name: str, kind: str = "brdf"
) -> onnx.ModelProto:
    inputs, out = _io(kind)
    graph = helper.make_graph(nodes, name, inputs, [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def constant_fold_bomb(k: int = 16384) -> onnx.ModelProto:
    """A BRDF whose only large tensor is computed from initialisers alone: ``[K, 1]`` and
    ``[1, K]`` initialisers (``8 K`` bytes) added to ``[K, K]`` (``4 K^2`` bytes), reduced to
    a scalar and multiplied into ``wi``. onnxruntime folds it when it opens the model."""
    inits = [
        numpy_helper.from_array(np.ones((k, 1), np.float32), "col"),
        numpy_helper.from_array(np.ones((1, k), np.float32), "row"),
    ]
    nodes = [
        helper.make_node("Add", ["col", "row"], ["square"], name="fold_add"),
        helper.make_node("ReduceSum", ["square"], ["total"], keepdims=0, name="fold_sum"),
        helper.make_node("Mul", ["wi", "total"], ["rgb"], name="scale"),
    ]
    return _brdf_model(nodes, inits, "constant_fold_bomb")


def quadratic_bomb() -> onnx.ModelProto:
    """A BRDF with an ``[N, N]`` intermediate from allow-listed operators only: ``wi``'s
    first column ``[N, 1]`` (Slice), its transpose ``[1, N]``, their broadcast sum ``[N, N]``,
    a mean over the second axis ``[N, 1]`` expanded to ``wi``'s shape ``[N, 3]``."""
    inits = [
        numpy_helper.from_array(np.array([0], np.int64), "start"),
        numpy_helper.from_array(np.array([1], np.int64), "end"),
        numpy_helper.from_array(np.array([1], np.int64), "axis"),
    ]
    nodes = [
        helper.make_node("Slice", ["wi", "start", "end", "axis"], ["column"], name="column"),
        helper.make_node("Transpose", ["column"], ["line"], perm=[1, 0], name="line"),
        helper.make_node("Add", ["column", "line"], ["square"], name="square"),
        helper.make_node("ReduceMean", ["square"], ["mean"], axes=[1], keepdims=1, name="mean"),
        helper.make_node("Shape", ["wi"], ["wi_shape"], name="wi_shape"),
        helper.make_node("Expand", ["mean", "wi_shape"], ["rgb"], name="expand"),
    ]
    return _brdf_model(nodes, inits, "quadratic_bomb")


def runtime_width_model(width: int = 4, kind: str = "brdf") -> onnx.ModelProto:
    """A ``kind`` model whose output is ``[N, width]`` at run time although shape inference
    cannot tell: the first ``width`` columns of ``concat(wi, wo)``, sliced to an end computed
    from the inputs' values (``max(wi * 0) + width``). Its declared output is ``[N, C]``, a symbolic
    last dimension (allowed; each evaluation checks it)."""
    inits = [
        numpy_helper.from_array(np.array([0.0], np.float32), "zero"),
        numpy_helper.from_array(np.array([float(width)], np.float32), "width"),
        numpy_helper.from_array(np.array([0], np.int64), "start"),
        numpy_helper.from_array(np.array([1], np.int64), "axis"),
        numpy_helper.from_array(np.array([1], np.int64), "one"),
    ]
    nodes = [
        helper.make_node("Concat", ["wi", "wo"], ["both"], axis=1),
        helper.make_node("Mul", ["wi", "zero"], ["zeros"]),
        helper.make_node("ReduceMax", ["zeros"], ["top"], keepdims=1),
        helper.make_node("Reshape", ["top", "one"], ["flat"]),
        helper.make_node("Add", ["flat", "width"], ["end_f"]),
        helper.make_node("Cast", ["end_f"], ["end"], to=TensorProto.INT64),
        helper.make_node("Slice", ["both", "start", "end", "axis"], ["rgb"]),
    ]
    model = _brdf_model(nodes, inits, "runtime_width", kind)
    dim = model.graph.output[0].type.tensor_type.shape.dim[1]
    dim.Clear()
    dim.dim_param = "C"
    return model


def hidden_square_model() -> onnx.ModelProto:
    """:func:`quadratic_bomb` with its ``[N, 1]`` column cut to an end computed from the
    inputs' values (``max(wi * 0) + 1``), so that shape inference cannot tell its width, nor
    that the broadcast sum is ``[N, N]``: a graph the upload check must let through, whose
    cost only the evaluation's chunks bound. ``rgb`` is row ``i``'s ``wi.x`` plus the mean
    ``wi.x`` of its onnxruntime call's rows, expanded to ``[N, 3]``."""
    inits = [
        numpy_helper.from_array(np.array([0.0], np.float32), "zero"),
        numpy_helper.from_array(np.array([1.0], np.float32), "one_f"),
        numpy_helper.from_array(np.array([1], np.int64), "one"),
        numpy_helper.from_array(np.array([0], np.int64), "start"),
        numpy_helper.from_array(np.array([1], np.int64), "axis"),
    ]
    nodes = [
        helper.make_node("Mul", ["wi", "zero"], ["zeros"]),
        helper.make_node("ReduceMax", ["zeros"], ["top"], keepdims=1),
        helper.make_node("Reshape", ["top", "one"], ["flat"]),
        helper.make_node("Add", ["flat", "one_f"], ["end_f"]),
        helper.make_node("Cast", ["end_f"], ["end"], to=TensorProto.INT64),
        helper.make_node("Slice", ["wi", "start", "end", "axis"], ["column"], name="column"),
        helper.make_node("Transpose", ["column"], ["line"], perm=[1, 0], name="line"),
        helper.make_node("Add", ["column", "line"], ["square"], name="square"),
        helper.make_node("ReduceMean", ["square"], ["mean"], axes=[1], keepdims=1, name="mean"),
        helper.make_node("Shape", ["wi"], ["wi_shape"], name="wi_shape"),
        helper.make_node("Expand", ["mean", "wi_shape"], ["rgb"], name="expand"),
    ]
    return _brdf_model(nodes, inits, "hidden_square")
