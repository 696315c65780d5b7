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
