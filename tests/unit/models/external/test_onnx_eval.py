"""Evaluating a user's ONNX model at a bounded cost: onnxruntime is called on chunks whose
intermediate tensors stay within ``CALL_BYTES``, from the bytes per row that shape inference
with a symbolic batch gives; a graph whose sizes inference cannot tell gets small chunks; a
failure at evaluation names the model by the label it was opened with.

References: the graphs of :mod:`tests.helpers.onnx_models` (written with ``onnx.helper``),
whose tensor shapes are read off their construction; numpy for the expected values.
"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from models.external.onnx_model import (
    CALL_BYTES,
    CHUNK,
    UNKNOWN_SHAPE_CHUNK,
    OnnxEvalError,
    load_onnx,
)
from tests.helpers.onnx_models import hidden_square_model, lambert_model, runtime_width_model, save

WIDE = 256


def _wide_brdf() -> onnx.ModelProto:
    """``rgb = relu(wi W) V`` with a ``[N, WIDE]`` hidden layer: 8 WIDE + 12 bytes per row
    (MatMul and Relu outputs, then ``rgb``)."""
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["N", 3]) for n in ("wi", "wo")]
    out = helper.make_tensor_value_info("rgb", TensorProto.FLOAT, ["N", 3])
    rng = np.random.default_rng(3)
    inits = [
        numpy_helper.from_array(rng.normal(size=(3, WIDE)).astype(np.float32), "w"),
        numpy_helper.from_array(rng.normal(size=(WIDE, 3)).astype(np.float32) / WIDE, "v"),
    ]
    nodes = [
        helper.make_node("MatMul", ["wi", "w"], ["h"]),
        helper.make_node("Relu", ["h"], ["a"]),
        helper.make_node("MatMul", ["a", "v"], ["rgb"]),
    ]
    graph = helper.make_graph(nodes, "wide", inputs, [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def _directions(n: int) -> np.ndarray:
    v = np.random.default_rng(n).normal(size=(n, 3)).astype(np.float32)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test01_chunks_keep_the_intermediates_within_the_call_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 256-wide hidden layer is 2060 bytes of intermediates per row: a call holds at most
    ``CALL_BYTES`` of them (here 64 KiB: 31 rows), not ``CHUNK`` rows. The values equal
    numpy's of the same weights (float32 sums of 256 products: rtol 1e-4)."""
    import models.external.onnx_model as onnx_model

    monkeypatch.setattr(onnx_model, "CALL_BYTES", 64 * 1024)
    model = _wide_brdf()
    m = load_onnx(save(model, tmp_path / "wide.onnx"), "brdf", threads=1)
    per_row = 4 * (2 * WIDE + 3)
    assert m.chunk == 64 * 1024 // per_row == 31
    monkeypatch.undo()
    assert load_onnx(tmp_path / "wide.onnx", "brdf").chunk == min(CHUNK, CALL_BYTES // per_row)
    n = 2 * m.chunk + 5
    wi = _directions(n)
    out = m.eval(wi, wi)
    assert m.stats.calls == 3 and m.stats.rows == n
    w, v = (numpy_helper.to_array(t) for t in model.graph.initializer)
    np.testing.assert_allclose(out, np.maximum(wi @ w, 0) @ v, rtol=1e-4, atol=1e-6)


def test02_a_graph_of_unknown_sizes_gets_small_chunks(tmp_path: Path) -> None:
    """The ``[N, N]`` square hidden from shape inference passes the upload check; evaluated,
    each call has at most ``UNKNOWN_SHAPE_CHUNK`` rows, so the square is at most 64 MiB
    however large the batch. Each row's value is its ``wi.x`` plus its call's mean
    ``wi.x`` (the graph's construction), which shows the calls' boundaries."""
    m = load_onnx(save(hidden_square_model(), tmp_path / "hidden.onnx"), "brdf", threads=1)
    assert m.chunk == UNKNOWN_SHAPE_CHUNK
    n = 2 * UNKNOWN_SHAPE_CHUNK + 7
    wi = _directions(n)
    out = m.eval(wi, wi)
    assert m.stats.calls == 3
    x = wi[:, 0].astype(np.float64)
    means = np.concatenate(
        [
            np.full(len(c), c.mean())
            for c in np.split(x, [UNKNOWN_SHAPE_CHUNK, 2 * UNKNOWN_SHAPE_CHUNK])
        ]
    )
    # float32 means of up to 4096 values against float64 ones: atol 1e-5.
    np.testing.assert_allclose(out, np.repeat((x + means)[:, None], 3, 1), atol=1e-5)


def test03_a_wrong_output_width_names_the_model_by_its_label(tmp_path: Path) -> None:
    """An output of ``[rows, 4]`` at run time (hidden from inference): an
    :class:`OnnxEvalError` naming the label given (the user's ref), the shape and what the
    signature needs, not the store's file name."""
    path = save(runtime_width_model(4), tmp_path / "0123abcd.onnx")
    ref = "sha256:" + "ab" * 32
    m = load_onnx(path, "brdf", threads=1, label=ref)
    with pytest.raises(OnnxEvalError) as info:
        m.eval(_directions(5), _directions(5))
    msg = str(info.value)
    assert msg.startswith(f"{ref}: the model's output rgb has shape [5, 4] for 5 rows"), msg
    assert "needs [N, 3]" in msg and "0123abcd" not in msg


def test04_a_failure_in_texture_space_shading_is_a_job_failure(
    tmp_path: Path, mi: types.ModuleType
) -> None:
    """``evaluate.tss`` calls an ONNX BTF from its passes: the same failure is a
    :class:`JobFailed` (the job's one-line error) naming the ref."""
    from evaluators.tss.external import OnnxPlaneModel
    from jobapi.errors import JobFailed

    ref = "sha256:" + "cd" * 32
    path = save(runtime_width_model(4, "btf"), tmp_path / "w.onnx")
    plane = OnnxPlaneModel(load_onnx(path, "btf", threads=1, label=ref), mi)
    up = mi.Vector3f([0.0, 0.6], [0.0, 0.0], [1.0, 0.8])
    with pytest.raises(
        JobFailed, match=r"^sha256:(cd)+: the model's output rgb has shape \[2, 4\]"
    ):
        plane.eval(mi.Point2f([0.1, 0.2], [0.3, 0.4]), up, up)


class _FailingSession:
    """An onnxruntime session stand-in whose every run raises ``message``."""

    def __init__(self, message: str) -> None:
        self.message = message

    def run(self, names: list[str], feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        raise RuntimeError(self.message)


def test05_onnxruntime_failures_name_the_model(tmp_path: Path) -> None:
    """onnxruntime's own errors become an :class:`OnnxEvalError` naming the model; one that
    could not allocate (onnxruntime's message for an arena request it cannot get) becomes a
    ``MemoryError``, which the job reports as out of memory."""
    ref = "sha256:" + "ef" * 32
    m = load_onnx(save(lambert_model("brdf"), tmp_path / "l.onnx"), "brdf", threads=1, label=ref)
    wi = _directions(4)
    m.session = _FailingSession("[ONNXRuntimeError] : 2 : INVALID_ARGUMENT : bad input")
    with pytest.raises(OnnxEvalError, match=rf"^{ref}: onnxruntime failed on the model: .*bad"):
        m.eval(wi, wi)
    m.session = _FailingSession(
        "[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : Failed to allocate memory for requested "
        "buffer of size 17179869184"
    )
    with pytest.raises(MemoryError, match=rf"^{ref}: onnxruntime could not allocate"):
        m.eval(wi, wi)
