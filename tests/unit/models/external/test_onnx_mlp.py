"""ONNX graphs that are MLPs, compiled into the fused Dr.Jit kernel
(:mod:`models.external.onnx_mlp`), and the machine-independent counts (:mod:`models.counts`).

Oracles: onnxruntime (not our code) on the same file and the same random batches; the
closed form ``I W + (D - 1) W^2 + W O`` of a ``W x D`` MLP's multiply-adds; the JSON MLP
format's count for the same weights.

Tolerance against onnxruntime: both evaluate in float32, but in a different order (the fused
kernel sums each output in one fused multiply-add chain, onnxruntime's GEMM in blocks) and
with their own ``exp``/``log``/``tanh``. Each of the ``K <= 32`` terms of a sum rounds at
most by one float32 epsilon (6e-8) of the running magnitude, so a layer's relative error is
about ``K`` eps ~ 2e-6 and three layers and the activations stay below 1e-5 relative;
``rtol=2e-5`` with ``atol=1e-6`` (for outputs near 0, where a relative bound means nothing)
is that bound with a margin of 2, far below any modelling difference (a wrong weight or
activation changes outputs by 1e-2 and more).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from models.counts import mlp_macs
from models.external import load_external
from models.external.mlp import mlp_from_document
from models.external.onnx_mlp import (
    NotFusable,
    OnnxMlpMaterial,
    compile_onnx,
    graph_counts,
    open_onnx,
)
from models.external.onnx_model import OnnxMaterial, load_onnx
from models.fused_mlp import DenseLayer, random_layers, torch_mlp
from models.speed import cosine_pairs
from tests.helpers.onnx_models import lambert_model, save

RTOL, ATOL = 2e-5, 1e-6


def _batch(n: int = 4096, seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine-weighted pairs plus some below the horizon, and uv spanning several periods."""
    wi, wo = cosine_pairs(n, seed)
    rng = np.random.default_rng(seed)
    wi[: n // 8, 2] *= -1.0
    uv = (rng.random((n, 2)) * 3.0 - 1.0).astype(np.float32)
    return wi, wo, uv


def _export(module: Any, path: Path, kind: str) -> Path:
    from matforge.export_onnx import brdf_onnx, btf_onnx

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return (brdf_onnx if kind == "brdf" else btf_onnx)(module, path)


def _torch_brdf(layers: list[DenseLayer]) -> Any:
    import torch

    class Brdf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, wi: Any, wo: Any) -> Any:
            return self.mlp(torch.cat([wi, wo], dim=1))

    return Brdf()


def _torch_btf() -> Any:
    import torch

    torch.manual_seed(0)

    class Btf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch.nn.Sequential(
                torch.nn.Linear(8, 16), torch.nn.LeakyReLU(0.2), torch.nn.Linear(16, 16),
                torch.nn.Tanh(), torch.nn.Linear(16, 3), torch.nn.Sigmoid(),
            )  # fmt: skip

        def forward(self, uv: Any, wi: Any, wo: Any) -> Any:
            # A column slice, a single-column Gather + Unsqueeze, Exp, Mul, Add, Sub.
            shade = self.mlp(torch.cat([uv, wi, wo], 1)) * wi[:, 2:3]
            return shade + 0.01 * torch.exp(wo[:, 2]).unsqueeze(1) - wo[:, 0:1] * 0.001

    return Btf()


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("onnx-mlp")
    layers = random_layers(np.random.default_rng(0), 6, 32, 3, 3, last="softplus")
    return {
        "layers": layers,
        "brdf": _export(_torch_brdf(layers), d / "brdf.onnx", "brdf"),
        "btf": _export(_torch_btf(), d / "btf.onnx", "btf"),
    }


@pytest.mark.parametrize("kind", ["brdf", "btf"])
def test01_torch_exports_run_fused_and_match_onnxruntime(
    mi: Any, exported: dict[str, Any], kind: str
) -> None:
    """The graphs ``torch.onnx.export`` writes for an ``nn.Sequential`` MLP (Concat, Gemm,
    Relu/LeakyRelu/Tanh/Sigmoid/Softplus, Slice, Gather, Unsqueeze, Exp, Mul, Add, Sub)
    open as ``drjit-fused`` and agree with onnxruntime on the same file."""
    path = exported[kind]
    fused = open_onnx(path, kind)
    assert isinstance(fused, OnnxMlpMaterial) and fused.runtime == "drjit-fused"
    assert isinstance(load_external(path, kind), OnnxMlpMaterial)
    ort = load_onnx(path, kind)
    for seed in (1, 2):
        wi, wo, uv = _batch(seed=seed)
        u = uv if kind == "btf" else None
        ref = ort.eval(wi, wo, u)
        np.testing.assert_allclose(fused.eval(wi, wo, u), ref, rtol=RTOL, atol=ATOL)
        np.testing.assert_allclose(fused.eval_numpy(wi, wo, u), ref, rtol=RTOL, atol=ATOL)


def _graph(nodes: list[Any], inits: list[Any], kind: str = "brdf") -> onnx.ModelProto:
    names = ("uv", "wi", "wo") if kind == "btf" else ("wi", "wo")
    dims = {"uv": 2, "wi": 3, "wo": 3}
    ins = [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["N", dims[n]]) for n in names]
    out = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, ["N", 3])
    graph = helper.make_graph(nodes, "g", ins, [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def _handwritten(rng: np.random.Generator) -> onnx.ModelProto:
    """MatMul + Add (bias folded), Split, Div, Clip, Max, Pow, Abs, Sqrt, Softplus, Constant."""
    f = lambda a, n: numpy_helper.from_array(np.asarray(a, np.float32), n)  # noqa: E731
    inits = [
        f(rng.normal(size=(6, 8)), "w0"), f(rng.normal(size=8), "b0"),
        f(rng.normal(size=(4, 3)), "w1"), f(rng.normal(size=(1, 3)), "b1"),
        f(0.0, "lo"), f(4.0, "hi"), f(2.0, "two"),
        numpy_helper.from_array(np.array([4, 4], np.int64), "parts"),
    ]  # fmt: skip
    nodes = [
        helper.make_node("Concat", ["wi", "wo"], ["x"], axis=1),
        helper.make_node("MatMul", ["x", "w0"], ["xw"]),
        helper.make_node("Add", ["b0", "xw"], ["h0"]),
        helper.make_node("Split", ["h0", "parts"], ["ha", "hb"], axis=1),
        helper.make_node("Clip", ["ha", "lo", "hi"], ["ca"]),
        helper.make_node("Abs", ["hb"], ["ab"]),
        helper.make_node("Constant", [], ["one"], value=f(1.0, "one")),
        helper.make_node("Add", ["ab", "one"], ["ab1"]),
        helper.make_node("Sqrt", ["ab1"], ["sb"]),
        helper.make_node("Div", ["ca", "sb"], ["q"]),
        helper.make_node("Pow", ["q", "two"], ["q2"]),
        helper.make_node("Max", ["q2", "ca"], ["m"]),
        helper.make_node("MatMul", ["m", "w1"], ["y"]),
        helper.make_node("Sub", ["y", "b1"], ["y1"]),
        helper.make_node("Softplus", ["y1"], ["rgb"]),
    ]
    return _graph(nodes, inits)


def test02_handwritten_graph_matches_onnxruntime(mi: Any, tmp_path: Path) -> None:
    """A graph written with ``onnx.helper`` with the other recognised operators, a bias
    ``Add`` with the constant first and a ``Sub`` of a constant bias: compiled (both
    products as dense layers), and equal to onnxruntime's values."""
    path = save(_handwritten(np.random.default_rng(5)), tmp_path / "hand.onnx")
    fused = open_onnx(path, "brdf")
    assert isinstance(fused, OnnxMlpMaterial)
    assert fused.program.dense_shapes == ((6, 8), (4, 3))
    wi, wo, _ = _batch()
    ref = load_onnx(path, "brdf").eval(wi, wo)
    np.testing.assert_allclose(fused.eval(wi, wo), ref, rtol=RTOL, atol=ATOL)


def test03_other_graphs_stay_in_onnxruntime(tmp_path: Path) -> None:
    """A graph with an operator the compiler does not know (``Reshape``) opens in
    onnxruntime, labelled so, and :class:`NotFusable` names the node; ``runtime:
    onnxruntime`` forces onnxruntime for a recognised one."""
    opaque = save(lambert_model("btf"), tmp_path / "opaque.onnx")
    model = open_onnx(opaque, "btf")
    assert isinstance(model, OnnxMaterial) and model.runtime == "onnxruntime"
    with pytest.raises(NotFusable, match=r"Reshape"):
        compile_onnx(onnx.load(str(opaque)), "btf", "opaque.onnx")
    plain = save(lambert_model("btf", opaque=False), tmp_path / "plain.onnx")
    assert open_onnx(plain, "btf").runtime == "drjit-fused"
    assert open_onnx(plain, "btf", runtime="onnxruntime").runtime == "onnxruntime"
    with pytest.raises(ValueError, match="runtime must be"):
        open_onnx(plain, "btf", runtime="torch")


def test04_not_fusable_cases(tmp_path: Path) -> None:
    """A product by a non-constant matrix, a slice along the batch and a per-row constant
    are refused with the node named (each would be wrong if compiled per column)."""
    w = numpy_helper.from_array(np.ones((3, 3), np.float32), "w")
    prod = _graph([helper.make_node("MatMul", ["wi", "wo"], ["rgb"])], [])
    with pytest.raises(NotFusable, match=r"MatMul.*not a constant"):
        compile_onnx(prod, "brdf")
    idx = [numpy_helper.from_array(np.array([v], np.int64), n)
           for v, n in ((0, "s"), (2, "e"), (0, "ax"))]  # fmt: skip
    batch = _graph(
        [helper.make_node("Slice", ["wi", "s", "e", "ax"], ["a"]),
         helper.make_node("MatMul", ["a", "w"], ["rgb"])], [w, *idx],
    )  # fmt: skip
    with pytest.raises(NotFusable, match="batch axis"):
        compile_onnx(batch, "brdf")
    rows = numpy_helper.from_array(np.ones((2, 3), np.float32), "rows")
    per_row = _graph([helper.make_node("Add", ["wi", "rows"], ["rgb"])], [rows])
    with pytest.raises(NotFusable, match="varies along the batch"):
        compile_onnx(per_row, "brdf")


@pytest.mark.parametrize(("width", "depth", "n_in", "n_out"), [(16, 2, 6, 3), (32, 3, 6, 3),
                                                              (64, 1, 8, 3)])  # fmt: skip
def test05_counts_closed_form_and_onnx_equals_json(
    tmp_path: Path, width: int, depth: int, n_in: int, n_out: int
) -> None:
    """A ``W x D`` MLP with ``I`` inputs and ``O`` outputs has ``I W + (D - 1) W^2 + W O``
    multiply-adds, counted the same from its JSON document and from its ONNX export (graph
    nodes and inferred shapes); bytes read: its float32 weights and biases, both ways."""
    import torch

    layers = random_layers(np.random.default_rng(1), n_in, width, depth, n_out, last="exp")
    expected = n_in * width + (depth - 1) * width * width + width * n_out
    assert mlp_macs(n_in, width, depth, n_out) == expected
    params = sum(ly.weight.size + ly.bias.size for ly in layers)
    doc = {
        "format": "matforge.mlp-brdf/1" if n_in == 6 else "matforge.mlp-btf/1",
        "inputs": ["wi", "wo"] if n_in == 6 else ["uv", "wi", "wo"],
        "layers": [{"weight": ly.weight.tolist(), "bias": ly.bias.tolist(),
                    "activation": ly.activation} for ly in layers],
        "output": {"combine": "network", "activation": "identity"},
    }  # fmt: skip
    kind = "brdf" if n_in == 6 else "btf"
    material = mlp_from_document(doc)
    assert (material.macs_per_eval, material.bytes_per_eval) == (expected, 4 * params)

    class Head(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, *xs: Any) -> Any:
            return self.mlp(torch.cat(xs, 1))[:, :3]

    path = _export(Head(), tmp_path / "m.onnx", kind)
    counted = graph_counts(onnx.load(str(path)))
    assert counted == {"macs_per_eval": expected, "bytes_per_eval": 4 * params}
    model = open_onnx(path, kind)
    assert (model.macs_per_eval, model.bytes_per_eval) == (expected, 4 * params)
    assert open_onnx(path, kind, runtime="onnxruntime").macs_per_eval == expected


def test06_gather_table_counts_what_one_lookup_reads(tmp_path: Path) -> None:
    """A constant table read through ``Gather`` counts the gathered elements, not the
    table: a 1000 x 3 table read at one row per evaluation is 12 bytes, not 12000."""
    table = numpy_helper.from_array(np.ones((1000, 3), np.float32), "table")
    idx = numpy_helper.from_array(np.array([0], np.int64), "idx")
    scale = numpy_helper.from_array(np.array([999.0], np.float32), "scale")
    nodes = [
        helper.make_node("Gather", ["wi", "idx"], ["x"], axis=1),
        helper.make_node("Mul", ["x", "scale"], ["xs"]),
        helper.make_node("Abs", ["xs"], ["xa"]),
        helper.make_node("Cast", ["xa"], ["i"], to=TensorProto.INT64),
        helper.make_node("Squeeze", ["i", "one"], ["i1"]),
        helper.make_node("Gather", ["table", "i1"], ["rgb"], axis=0),
    ]
    one = numpy_helper.from_array(np.array([1], np.int64), "one")
    counted = graph_counts(_graph(nodes, [table, idx, scale, one]))
    assert counted == {"macs_per_eval": 0, "bytes_per_eval": 12 + 4}


def test07_cost_document_times_the_fused_kernel_and_counts(
    mi: Any, exported: dict[str, Any]
) -> None:
    """The cost document of a recognised ONNX BRDF times the fused kernel (its method says
    so) and carries the counts; of the same file in onnxruntime, the same counts."""
    from models.external.cost import FUSED_METHOD, measure_cost

    fused = measure_cost(open_onnx(exported["brdf"], "brdf"), batch=4096, repeats=1)
    assert (fused["runtime"], fused["method"]) == ("drjit-fused", FUSED_METHOD)
    assert fused["ns_per_eval"] > 0
    macs = mlp_macs(6, 32, 3, 3)
    assert fused["macs_per_eval"] == macs
    ort = measure_cost(open_onnx(exported["brdf"], "brdf", runtime="onnxruntime"), batch=4096,
                       repeats=1)  # fmt: skip
    assert ort["runtime"] == "onnxruntime"
    assert (ort["macs_per_eval"], ort["bytes_per_eval"]) == (macs, fused["bytes_per_eval"])
    # Both are typed records of the score's cost document; a record without the counts is not.
    from jobapi.documents import DocumentError, check_typed
    from models.external.cost import COST_FORMAT, CostDocument

    check_typed("cost", {"format": COST_FORMAT, "candidates": {"a": fused, "b": ort}},
                CostDocument)  # fmt: skip
    old = {k: v for k, v in fused.items() if k != "macs_per_eval"}
    with pytest.raises(DocumentError, match="macs_per_eval"):
        check_typed("cost", {"format": COST_FORMAT, "candidates": {"a": old}}, CostDocument)


def test08_too_large_to_unroll_stays_in_onnxruntime(tmp_path: Path) -> None:
    """A 512-wide layer pair (2 x 3 x 512 + 512 x 512 multiply-adds, over the unroll limit)
    is not compiled: it runs in onnxruntime, and the reason names the limit."""
    from models.external.onnx_mlp import MAX_UNROLLED

    rng = np.random.default_rng(0)
    f = lambda a, n: numpy_helper.from_array(np.asarray(a, np.float32), n)  # noqa: E731
    inits = [f(rng.normal(size=(3, 512)), "w0"), f(rng.normal(size=(512, 512)), "w1"),
             f(rng.normal(size=(512, 3)), "w2")]  # fmt: skip
    nodes = [
        helper.make_node("MatMul", ["wi", "w0"], ["a"]),
        helper.make_node("MatMul", ["a", "w1"], ["b"]),
        helper.make_node("MatMul", ["b", "w2"], ["rgb"]),
    ]
    assert 3 * 512 + 512 * 512 + 512 * 3 > MAX_UNROLLED
    path = save(_graph(nodes, inits), tmp_path / "wide.onnx")
    with pytest.raises(NotFusable, match=f"more than {MAX_UNROLLED} operations"):
        compile_onnx(onnx.load(str(path)), "brdf")
    model = open_onnx(path, "brdf")
    assert model.runtime == "onnxruntime" and model.macs_per_eval == 3 * 512 * 2 + 512 * 512


def test09_constant_subgraphs_are_folded(mi: Any, tmp_path: Path) -> None:
    """Nodes of constants only (``Mul``, ``Concat`` of constants, a ``Shape`` of a constant)
    are computed at load and used as constants; the result equals onnxruntime's."""
    f = lambda a, n: numpy_helper.from_array(np.asarray(a, np.float32), n)  # noqa: E731
    inits = [f([[0.5]], "c1"), f([[2.0, 3.0]], "c2"), f([[1.0]], "c3"), f(np.ones((2, 2)), "m")]
    nodes = [
        helper.make_node("Mul", ["c1", "c2"], ["c12"]),  # [[1, 1.5]]
        helper.make_node("Concat", ["c12", "c3"], ["bias"], axis=1),  # [[1, 1.5, 1]]
        helper.make_node("Shape", ["m"], ["ms"]),
        helper.make_node("Cast", ["ms"], ["msf"], to=TensorProto.FLOAT),  # [2, 2]
        helper.make_node("ReduceSum", ["msf"], ["four"], keepdims=1),  # [4]
        helper.make_node("Mul", ["wi", "four"], ["w4"]),
        helper.make_node("Add", ["w4", "bias"], ["rgb"]),
    ]
    path = save(_graph(nodes, inits), tmp_path / "folded.onnx")
    model = open_onnx(path, "brdf")
    assert isinstance(model, OnnxMlpMaterial)
    assert [n.op for n in model.program.nodes] == ["Mul", "Add"]  # folded once, not per trace
    wi, wo, _ = _batch(512)
    ref = load_onnx(path, "brdf").eval(wi, wo)
    np.testing.assert_allclose(ref, wi * 4.0 + np.array([1.0, 1.5, 1.0], np.float32), rtol=1e-6)
    np.testing.assert_allclose(model.eval(wi, wo), ref, rtol=RTOL, atol=ATOL)


def test10_a_torch_ggx_with_normalize_is_compiled(mi: Any, tmp_path: Path) -> None:
    """A torch GGX + Lambert BRDF (``tests/helpers/external_models.py``: ``normalize``, a
    column sum, ``Pow``, ``Sqrt``, ``Div``, ``Clip``) exports ``ReduceL2``, ``Shape``,
    ``Expand`` and ``ReduceSum``: compiled, and equal to onnxruntime on cosine-weighted
    pairs (the tolerance of the module docstring: a few float32 roundings per operation)."""
    import torch

    from tests.helpers.external_models import ggx_lambert

    class Ggx(torch.nn.Module):
        def forward(self, wi: Any, wo: Any) -> Any:
            kd, eta = torch.tensor([0.2, 0.3, 0.4]), torch.tensor([1.5, 1.6, 1.7])
            return ggx_lambert(wi, wo, kd, 0.3, eta)

    path = _export(Ggx(), tmp_path / "ggx.onnx", "brdf")
    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert {"ReduceL2", "Shape", "Expand", "ReduceSum"} <= ops
    fused = open_onnx(path, "brdf")
    assert isinstance(fused, OnnxMlpMaterial)
    wi, wo = cosine_pairs(4096, 9)
    ref = load_onnx(path, "brdf").eval(wi, wo)
    np.testing.assert_allclose(fused.eval(wi, wo), ref, rtol=RTOL, atol=ATOL)


def test11_comparisons_and_where_a_horizon_mask(mi: Any, tmp_path: Path) -> None:
    """``torch.where`` of comparisons (``Greater``, ``And``, ``Not``, ``LessOrEqual``) and a
    comparison cast to float, around an MLP: compiled, and equal to onnxruntime on a batch
    with pairs below the horizon (where the mask decides)."""
    import torch

    layers = random_layers(np.random.default_rng(2), 6, 16, 2, 3, last="softplus")

    class Masked(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.mlp = torch_mlp(layers)

        def forward(self, wi: Any, wo: Any) -> Any:
            y = self.mlp(torch.cat([wi, wo], dim=1))
            up = (wi[:, 2:3] > 0) & ~(wo[:, 2:3] <= 0)
            grazing = (wo[:, 2:3] < 0.2).float()
            return torch.where(up, y * (1.0 - 0.5 * grazing), 0.0)

    path = _export(Masked(), tmp_path / "masked.onnx", "brdf")
    ops = {n.op_type for n in onnx.load(str(path)).graph.node}
    assert {"Greater", "And", "Not", "LessOrEqual", "Where", "Cast"} <= ops
    fused = open_onnx(path, "brdf")
    assert isinstance(fused, OnnxMlpMaterial)
    wi, wo, _ = _batch()
    ref = load_onnx(path, "brdf").eval(wi, wo)
    assert (ref == 0).any() and (ref > 0).any()
    np.testing.assert_allclose(fused.eval(wi, wo), ref, rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(fused.eval_numpy(wi, wo), ref, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("arity", [1, 2, 3])
def test12_every_allowed_operator_compiles_or_is_refused(arity: int) -> None:
    """Each operator of the upload allowlist, on the graph inputs (and a constant): the
    compiler either compiles it or refuses it with :class:`NotFusable`, never fails
    otherwise (the graphs need not be valid: the compiler must not rely on it)."""
    from storage.formats.onnx import ALLOWED_OPS

    const = numpy_helper.from_array(np.ones((1, 3), np.float32), "k")
    args = ["wi", "wo", "k"][:arity]
    for op in sorted(ALLOWED_OPS):
        model = _graph([helper.make_node(op, args, ["rgb"])], [const])
        try:
            compile_onnx(model, "brdf", f"{op}.onnx")
        except NotFusable:
            pass
