"""ONNX uploads are data, not code: :mod:`storage.formats.onnx` refuses every file that
strays from the documented signature or the operator allowlist, naming the file and the
problem.

Reference: the signature and limits as ``docs/onnx-models.md`` states them; each bad file
is a valid model (built with ``onnx.helper``, independent of the validator) with one thing
changed, so the refusal can only come from that one thing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from storage.errors import FormatError, TooLargeError
from storage.formats import validate_file
from storage.formats.onnx import MAX_ONNX_BYTES, batch_cost, check_onnx_file, onnx_kind
from tests.helpers.onnx_models import (
    constant_fold_bomb,
    lambert_model,
    quadratic_bomb,
    runtime_width_model,
    save,
)


def _refusal(tmp_path: Path, model: onnx.ModelProto | bytes, err: type = FormatError) -> str:
    path = tmp_path / "m.onnx"
    path.write_bytes(model if isinstance(model, bytes) else model.SerializeToString())
    with pytest.raises(err) as info:
        validate_file(path, "m.onnx")
    msg = str(info.value)
    assert msg.startswith("m.onnx: "), msg
    return msg


@pytest.mark.parametrize("kind", ["brdf", "btf"])
def test01_valid_models_pass_and_name_their_kind(tmp_path: Path, kind: str) -> None:
    model = lambert_model(kind)
    path = save(model, tmp_path / "ok.onnx")
    assert validate_file(path, "ok.onnx") == "application/x-onnx"
    assert onnx_kind(model, "ok.onnx") == kind
    check_onnx_file(path, "ok.onnx", kind)
    other = "btf" if kind == "brdf" else "brdf"
    with pytest.raises(FormatError, match=f"declared kind '{other}' needs inputs"):
        check_onnx_file(path, "ok.onnx", other)


def test02_truncated_and_garbage_bytes(tmp_path: Path) -> None:
    data = lambert_model("btf").SerializeToString()
    for cut in (1, 7, len(data) // 3, len(data) // 2, len(data) - 3):
        _refusal(tmp_path, data[:cut])
    assert "empty file" in _refusal(tmp_path, b"")
    assert "does not decode" in _refusal(tmp_path, b"\xff" * 100)


def test03_wrong_signatures(tmp_path: Path) -> None:
    m = lambert_model("btf")
    m.graph.input[0].name = "xy"
    assert "inputs (xy, wi, wo) match no signature" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.graph.input[1].type.tensor_type.elem_type = TensorProto.DOUBLE
    assert "input 'wi' must be float32, not DOUBLE" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.graph.input[1].type.tensor_type.shape.dim[0].dim_value = 64
    assert "input 'wi' has a fixed batch dimension 64" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.graph.input[0].type.tensor_type.shape.dim[1].dim_value = 3
    assert "input 'uv' must have shape [N, 2]" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.graph.output[0].name = "color"
    assert "outputs (color) must be exactly one named 'rgb'" in _refusal(tmp_path, m)


def test04_operators_domains_and_opsets(tmp_path: Path) -> None:
    m = lambert_model("btf")
    m.graph.node.append(helper.make_node("RandomNormal", [], ["noise"], shape=[1]))
    assert "operator RandomNormal is not allowed" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.graph.node[1].domain = "com.evil"
    m.opset_import.append(helper.make_opsetid("com.evil", 1))
    assert "custom operator domain 'com.evil'" in _refusal(tmp_path, m)

    m = lambert_model("btf", opset=7)
    assert "opset 7 is outside the supported" in _refusal(tmp_path, m)

    m = lambert_model("btf")
    m.functions.append(helper.make_function("evil", "f", ["a"], ["b"], [], []))
    assert "model-local functions are not allowed" in _refusal(tmp_path, m)


def test05_initialiser_sizes_and_external_data(tmp_path: Path) -> None:
    m = lambert_model("btf")
    huge = TensorProto(name="huge", data_type=TensorProto.FLOAT, dims=[2**31], raw_data=b"\0" * 4)
    m.graph.initializer.append(huge)
    msg = _refusal(tmp_path, m, TooLargeError)
    assert "initialiser 'huge' declares 8192.0 MiB" in msg

    m = lambert_model("btf")
    m.graph.initializer[3].raw_data = m.graph.initializer[3].raw_data[:8]
    assert "initialiser 'k' declares shape [1, 3] (12 bytes) but stores 8 bytes" in _refusal(
        tmp_path, m
    )

    m = lambert_model("btf")
    t = m.graph.initializer[3]
    t.data_location = TensorProto.EXTERNAL
    t.ClearField("raw_data")
    t.external_data.add(key="location", value="/etc/passwd")
    assert "initialiser 'k' stores its data in an external file" in _refusal(tmp_path, m)


def test06_over_the_file_size_limit_is_413_before_reading(tmp_path: Path) -> None:
    path = tmp_path / "big.onnx"
    with path.open("wb") as f:
        f.truncate(MAX_ONNX_BYTES + 1)  # sparse: nothing is read
    with pytest.raises(TooLargeError, match=r"^big.onnx: ONNX file of 64.0 MiB exceeds"):
        validate_file(path, "big.onnx")


def test07_checker_errors_are_format_errors(tmp_path: Path) -> None:
    # A node reading a tensor nobody defines: onnx.checker's complaint, as a FormatError.
    m = lambert_model("btf")
    m.graph.node[1].input[1] = "nowhere"
    assert "invalid ONNX graph" in _refusal(tmp_path, m)
    # A Constant node's value counts toward the initialiser bytes too.
    m = lambert_model("btf")
    big = numpy_helper.from_array(np.zeros(1, np.float32), "c")
    big.ClearField("raw_data")
    big.dims[:] = [2**30]
    m.graph.node.append(helper.make_node("Constant", [], ["c"], value=big))
    assert "declares 4096.0 MiB" in _refusal(tmp_path, m, TooLargeError)


def test08_expand_only_to_another_tensors_shape(tmp_path: Path) -> None:
    # Expand to a constant shape could ask for any amount of memory at evaluation time.
    m = lambert_model("btf")
    m.graph.initializer.append(numpy_helper.from_array(np.array([2**40, 3], np.int64), "shape"))
    m.graph.node.append(helper.make_node("Expand", ["rgb", "shape"], ["big"]))
    assert "Expand's shape must come straight from a Shape node" in _refusal(tmp_path, m)


def test09_a_constant_folded_tensor_over_the_initialiser_limit_is_413(tmp_path: Path) -> None:
    """``[K, 1] + [1, K]`` initialisers (128 KiB at K = 16384) fold to ``[K, K]``, 1 GiB:
    refused naming the node, with the size shape inference gives (4 K^2 bytes). At K = 64
    the same graph (16 KiB folded) passes: the size decides, not the pattern."""
    msg = _refusal(tmp_path, constant_fold_bomb(16384), TooLargeError)
    assert "node 'fold_add' (Add) computes 'square' [16384, 16384]" in msg, msg
    assert "from initialisers and constants only" in msg and "1024.0 MiB" in msg, msg
    path = save(constant_fold_bomb(64), tmp_path / "small.onnx")
    assert validate_file(path, "small.onnx") == "application/x-onnx"
    # Two folded squares of 3300^2 float32 (41.5 MiB each): each under the limit, over it
    # together.
    m = constant_fold_bomb(3300)
    m.graph.node.insert(1, helper.make_node("Mul", ["col", "row"], ["product"], name="fold_mul"))
    m.graph.node.insert(2, helper.make_node("Add", ["square", "product"], ["both"]))
    m.graph.node[3].input[0] = "both"
    msg = _refusal(tmp_path, m, TooLargeError)
    assert "the tensors of fixed size up to node 'fold_mul' (Mul) take 83.1 MiB in all" in msg, msg


def test10_an_intermediate_growing_faster_than_the_batch_is_refused(tmp_path: Path) -> None:
    """Slice(wi) ``[N, 1]`` -> Transpose ``[1, N]`` -> Add ``[N, N]``: every operator is on
    the allow-list, and the square is refused naming the node and its shape."""
    msg = _refusal(tmp_path, quadratic_bomb())
    assert "node 'square' (Add) makes 'square' of shape [N, N]" in msg, msg
    assert "grows faster than the batch N (N^2 elements" in msg, msg
    # The file's own value_info cannot hide it: declared small, inferred anew.
    m = quadratic_bomb()
    m.graph.value_info.append(helper.make_tensor_value_info("square", TensorProto.FLOAT, ["N", 1]))
    assert "of shape [N, N]" in _refusal(tmp_path, m)
    # Nor can inputs naming their batch dimension differently.
    m = quadratic_bomb()
    m.graph.input[1].type.tensor_type.shape.dim[0].dim_param = "batch"
    assert "of shape [N, N]" in _refusal(tmp_path, m)


def test11_an_output_inferred_with_the_wrong_width_is_refused(tmp_path: Path) -> None:
    """A declared ``[N, C]`` output that inference computes as ``[N, 4]``; the same shape
    hidden from inference (a value-dependent Slice) passes, for the run-time check."""
    m = lambert_model("brdf", opaque=False)  # its output shape is inferred
    m.graph.initializer[0].CopyFrom(numpy_helper.from_array(np.full((1, 4), 0.1, np.float32), "k"))
    m.graph.initializer[1].CopyFrom(numpy_helper.from_array(np.zeros((3, 4), np.float32), "zero"))
    dim = m.graph.output[0].type.tensor_type.shape.dim[1]
    dim.Clear()
    dim.dim_param = "C"
    assert "output 'rgb' is computed with shape [N, 4]" in _refusal(tmp_path, m)
    path = save(runtime_width_model(4), tmp_path / "hidden.onnx")
    assert validate_file(path, "hidden.onnx") == "application/x-onnx"


def test12_batch_cost_of_good_models(tmp_path: Path) -> None:
    """Bytes per row are the float32 node outputs' widths summed (the Lambert BTF: a
    ``[N, 1]`` cosine and the ``[N, 3]`` output, 16 bytes); a torch-exported MLP is fully
    inferred (nothing unknown) and accepted."""
    import torch

    from matforge.export_onnx import brdf_onnx

    assert batch_cost(lambert_model("btf"), "m.onnx").row_bytes == 4 * (1 + 3)
    net = torch.nn.Sequential(torch.nn.Linear(6, 32), torch.nn.ReLU(), torch.nn.Linear(32, 3))

    class Brdf(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = net

        def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return torch.exp(self.net(torch.cat([wi, wo], dim=1)))

    path = brdf_onnx(Brdf(), tmp_path / "mlp.onnx")
    assert validate_file(path, "mlp.onnx") == "application/x-onnx"
    cost = batch_cost(onnx.load(str(path)), "mlp.onnx")
    assert cost.unknown == () and cost.row_bytes >= 4 * (6 + 32 + 32 + 3 + 3), cost


def test13_torch_like_constants_pass_and_run(tmp_path: Path) -> None:
    """``torch.ones_like``, ``zeros_like`` and ``full_like`` export as ``Shape`` then
    ``ConstantOfShape``: a constant as big as a tensor the graph has, so allowed (it was
    refused), and onnxruntime runs the model to what torch computes."""
    import onnxruntime as ort
    import torch

    class Like(torch.nn.Module):
        def forward(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return wi * torch.ones_like(wi) + torch.zeros_like(wo) + torch.full_like(wi, 0.5)

    path = tmp_path / "like.onnx"
    n = torch.zeros(5, 3)
    torch.onnx.export(Like(), (n, n), str(path), input_names=["wi", "wo"], output_names=["rgb"],
                      dynamic_axes={k: {0: "n"} for k in ("wi", "wo", "rgb")}, opset_version=17,
                      dynamo=False)  # fmt: skip
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert "ConstantOfShape" in ops, ops
    check_onnx_file(path, "like.onnx", "brdf")
    wi = np.random.default_rng(0).random((7, 3), dtype=np.float32)
    (rgb,) = ort.InferenceSession(str(path)).run(None, {"wi": wi, "wo": wi})
    np.testing.assert_allclose(rgb, wi + 0.5, rtol=1e-6)  # float32 round-off of one add


def test14_constant_of_shape_only_to_another_tensors_shape(tmp_path: Path) -> None:
    m = lambert_model("btf")
    m.graph.initializer.append(numpy_helper.from_array(np.array([2**40, 3], np.int64), "shape"))
    m.graph.node.append(helper.make_node("ConstantOfShape", ["shape"], ["big"]))
    assert "ConstantOfShape's shape must come straight from a Shape node" in _refusal(tmp_path, m)
