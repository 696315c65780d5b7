"""ONNX material models: validation of a user's ``.onnx`` file, which is data, not code.

The documented signature (``docs/onnx-models.md``): one graph with float32 inputs, a
**dynamic** batch dimension ``N`` and one float32 output ``rgb`` ``[N, 3]``:

===========  =========================  ===================================================
kind         inputs                     meaning of ``rgb``
===========  =========================  ===================================================
``brdf``     ``wi`` [N,3], ``wo`` [N,3]  the plain BRDF in 1/sr (no cosine)
``btf``      ``uv`` [N,2], ``wi`` [N,3],  the BTF in ``generate.btf``'s convention (UBO2014:
             ``wo`` [N,3]                ``L_o / E_perp``, ``cos(theta_i)`` of the light
                                         ``wi`` included)
===========  =========================  ===================================================

The input names decide the kind: :func:`onnx_kind`. What :func:`validate_onnx` refuses,
each as a :class:`FormatError` naming the file and the problem (422), or a
:class:`TooLargeError` (413) for a file or initialisers over the limits:

- a file over :data:`MAX_ONNX_BYTES`, bytes that are not an ONNX protobuf (truncated,
  undecodable), a model that ``onnx.checker`` rejects;
- an opset of the default domain outside :data:`OPSET_RANGE`; any other domain (custom
  operators), model-local functions, training info, sparse initialisers;
- a node whose operator is not in :data:`ALLOWED_OPS` (no control flow, no subgraphs, no
  random or shape-generating operators), any graph-valued attribute;
- tensors stored as external data (a path on the server's disk), initialisers or
  ``Constant`` values whose declared size exceeds :data:`MAX_INITIALIZER_BYTES` in all, or
  whose stored bytes do not match their declared shape;
- more than :data:`MAX_NODES` nodes;
- inputs and outputs that are not exactly one of the two signatures above: names, ranks,
  a fixed last dimension (the output's may be symbolic: each evaluation checks it), a
  dynamic first one, float32.
- what shape inference with a symbolic batch ``N`` shows to cost memory out of proportion
  (:func:`batch_cost`): a tensor that grows faster than ``N``, a tensor computed from
  initialisers and constants only (folded by onnxruntime when it opens the model) over
  :data:`MAX_INITIALIZER_BYTES`, more than :data:`MAX_ROW_BYTES` per row, an output
  computed with a last dimension other than 3.

This module imports nothing of ours but :mod:`storage.errors`; ``onnx`` is imported lazily
so that reading other formats never pays for it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from storage.errors import FormatError, TooLargeError

#: The largest ``.onnx`` file accepted, in bytes.
MAX_ONNX_BYTES = 64 * 1024 * 1024
#: The most bytes all initialisers and ``Constant`` values may declare together.
MAX_INITIALIZER_BYTES = 64 * 1024 * 1024
#: The most nodes in the graph.
MAX_NODES = 10_000
#: The most bytes of intermediate tensors one row of the batch may need (:func:`batch_cost`).
MAX_ROW_BYTES = 16 * 1024 * 1024
#: The batch dimension's symbol in :func:`batch_cost`'s shape inference.
BATCH = "N"
#: Opset versions of the default (``ai.onnx``) domain accepted, inclusive; onnxruntime 1.32
#: runs all of them.
OPSET_RANGE = (13, 23)
#: Operators a small MLP or texture graph needs: arithmetic, activations, shape plumbing
#: with constant shapes, indexing and reductions. No control flow (``If``, ``Loop``,
#: ``Scan``), no random operators, nothing that makes a tensor of a data-dependent size
#: (``Tile``, ``Range``, ``Resize``, ``NonZero``). ``Expand`` (torch's ``normalize`` exports
#: one) and ``ConstantOfShape`` (torch's ``ones_like``, ``zeros_like``, ``full_like``) only
#: to the shape of another tensor: their shape input must be the output of a ``Shape``
#: node (:data:`SHAPED_OPS`).
ALLOWED_OPS = frozenset(
    {
        # linear algebra and arithmetic
        "Gemm", "MatMul", "Add", "Sub", "Mul", "Div", "Neg", "Abs", "Reciprocal", "Pow",
        "Sqrt", "Exp", "Log", "Max", "Min", "Clip", "Floor", "Ceil", "Round", "Sign", "Mod",
        "Sin", "Cos", "Tan", "Asin", "Acos", "Atan", "Erf", "Sum", "Mean",
        # activations
        "Relu", "LeakyRelu", "PRelu", "Elu", "Selu", "Celu", "Sigmoid", "HardSigmoid",
        "Tanh", "Softplus", "Softsign", "Softmax", "LogSoftmax", "Gelu", "HardSwish", "Mish",
        # comparisons and selection
        "Equal", "Greater", "GreaterOrEqual", "Less", "LessOrEqual", "Not", "And", "Or",
        "Where", "IsNaN", "IsInf",
        # shape plumbing
        "Concat", "Split", "Slice", "Reshape", "Flatten", "Squeeze", "Unsqueeze",
        "Transpose", "Identity", "Cast", "CastLike", "Shape", "Constant", "Expand",
        "ConstantOfShape",
        # indexing and textures
        "Gather", "GatherElements", "GatherND", "GridSample",
        # reductions and normalisation
        "ReduceSum", "ReduceMean", "ReduceMax", "ReduceMin", "ReduceProd", "ReduceL2",
        "ReduceSumSquare", "LayerNormalization", "BatchNormalization",
    }
)  # fmt: skip
#: Operators whose output size is their ``shape`` input (by its index): allowed only where
#: that input is a ``Shape`` node's output, so no graph can ask for more memory than a
#: tensor it already has.
SHAPED_OPS = {"Expand": 1, "ConstantOfShape": 0}
#: The two signatures: kind -> (input name -> last dimension), in order.
SIGNATURES: dict[str, dict[str, int]] = {
    "brdf": {"wi": 3, "wo": 3},
    "btf": {"uv": 2, "wi": 3, "wo": 3},
}
#: The one output: its name and last dimension.
OUTPUT = ("rgb", 3)
_DEFAULT_DOMAINS = ("", "ai.onnx")
_ITEMSIZE = {1: 4, 2: 1, 3: 1, 4: 2, 5: 2, 6: 4, 7: 8, 9: 1, 10: 2, 11: 8, 12: 4, 13: 8, 16: 2}


def _mib(n: int) -> str:
    return f"{n / 2**20:.1f} MiB"


def preload() -> None:
    """Import the ``onnx`` package now (about 2 s on a loaded 2-core machine), so that the
    first submission naming an ONNX model does not hold the process for it."""
    import onnx  # noqa: F401
    import onnx.shape_inference  # noqa: F401


def load_onnx_proto(path: Path, name: str) -> Any:
    """The ``onnx.ModelProto`` in ``path`` (size-checked, parsed, nothing else checked)."""
    import onnx
    from google.protobuf.message import DecodeError

    try:
        size = Path(path).stat().st_size
    except OSError as exc:
        raise FormatError(name, f"cannot read: {exc.strerror or exc}") from None
    if size > MAX_ONNX_BYTES:
        raise TooLargeError(
            f"{name}: ONNX file of {_mib(size)} exceeds the limit of {_mib(MAX_ONNX_BYTES)}"
        )
    if size == 0:
        raise FormatError(name, "empty file, not an ONNX model")
    data = Path(path).read_bytes()
    model = onnx.ModelProto()
    try:
        model.ParseFromString(data)
    except (DecodeError, RuntimeError, ValueError) as exc:
        if "alloc" in str(exc).lower():  # protobuf's arena under the checker's memory cap
            raise TooLargeError(
                f"{name}: decoding it needs more memory than file checks may use"
            ) from None
        raise FormatError(
            name, f"not an ONNX model: the protobuf does not decode (truncated?): {exc}"
        ) from None
    if not model.HasField("graph") or model.ir_version <= 0:
        raise FormatError(name, "not an ONNX model: no graph or IR version (truncated?)")
    return model


def _tensor_bytes(t: Any, where: str, name: str) -> int:
    """Declared bytes of a ``TensorProto``; refuses external data and stored bytes that do
    not match the declared shape."""
    import onnx

    if t.data_location == onnx.TensorProto.EXTERNAL or len(t.external_data):
        raise FormatError(
            name, f"{where} stores its data in an external file; embed all tensors in the .onnx"
        )
    itemsize = _ITEMSIZE.get(t.data_type)
    if itemsize is None:
        raise FormatError(name, f"{where} has an unsupported element type {t.data_type}")
    count = 1
    for d in t.dims:
        if d < 0:
            raise FormatError(name, f"{where} has a negative dimension {d}")
        count *= d
    declared = count * itemsize
    if declared > MAX_INITIALIZER_BYTES:
        raise TooLargeError(
            f"{name}: {where} declares {_mib(declared)}, over the limit of "
            f"{_mib(MAX_INITIALIZER_BYTES)} for all initialisers"
        )
    if t.string_data:
        raise FormatError(name, f"{where} holds strings")
    if t.HasField("raw_data"):
        stored = len(t.raw_data)
    else:  # typed fields: one entry per element (TensorProto's layout)
        field = {1: t.float_data, 7: t.int64_data, 11: t.double_data}.get(t.data_type)
        if field is None:
            field = t.uint64_data if t.data_type in (12, 13) else t.int32_data
        stored = len(field) * itemsize
    if stored != declared:
        raise FormatError(
            name,
            f"{where} declares shape {list(t.dims)} ({declared} bytes) but stores {stored} bytes",
        )
    return declared


def _dims(value_info: Any) -> tuple[int, list[Any]]:
    """``(elem_type, dims)``; a dim is an int, a str (symbolic) or ``None`` (unknown)."""
    tt = value_info.type.tensor_type
    if not value_info.type.HasField("tensor_type"):
        return -1, []
    dims: list[Any] = []
    for d in tt.shape.dim:
        if d.HasField("dim_value"):
            dims.append(d.dim_value)
        elif d.HasField("dim_param"):
            dims.append(d.dim_param)
        else:
            dims.append(None)
    return tt.elem_type, dims if tt.HasField("shape") else []


def _inferred_dims(value_info: Any) -> tuple[int, list[Any] | None]:
    """``(elem_type, dims)`` as :func:`_dims`, with ``dims`` ``None`` where no shape is known
    at all (a scalar has ``[]``)."""
    tt = value_info.type.tensor_type
    if not value_info.type.HasField("tensor_type") or not tt.HasField("shape"):
        return tt.elem_type, None
    return _dims(value_info)


def _check_tensor_io(vi: Any, last: int, what: str, name: str) -> None:
    import onnx

    elem, dims = _dims(vi)
    if elem != onnx.TensorProto.FLOAT:
        shown = onnx.TensorProto.DataType.Name(elem) if elem > 0 else "not a tensor"
        raise FormatError(name, f"{what} '{vi.name}' must be float32, not {shown}")
    if len(dims) != 2:
        raise FormatError(
            name, f"{what} '{vi.name}' must have rank 2 [N, {last}], got shape {dims or '?'}"
        )
    if isinstance(dims[0], int):
        raise FormatError(
            name,
            f"{what} '{vi.name}' has a fixed batch dimension {dims[0]}; the first dimension "
            "must be dynamic (a symbolic name such as 'N': dynamic_axes in torch.onnx.export)",
        )
    # An output's last dimension may be symbolic (torch's exporter often leaves a broadcast
    # symbolic): the evaluator checks every call's result is [rows, 3]. A fixed one must fit.
    if dims[1] != last and not (what == "output" and not isinstance(dims[1], int)):
        raise FormatError(
            name, f"{what} '{vi.name}' must have shape [N, {last}], got [{dims[0]}, {dims[1]}]"
        )


def onnx_kind(model: Any, name: str) -> str:
    """The kind (``"brdf"`` or ``"btf"``) whose signature ``model``'s inputs and output
    follow; :class:`FormatError` naming what differs otherwise."""
    graph = model.graph
    init_names = {t.name for t in graph.initializer}
    inputs = [vi for vi in graph.input if vi.name not in init_names]
    names = [vi.name for vi in inputs]
    kind = next((k for k, sig in SIGNATURES.items() if sorted(sig) == sorted(names)), None)
    if kind is None:
        expected = " or ".join(f"({', '.join(sig)})" for sig in SIGNATURES.values())
        raise FormatError(
            name,
            f"inputs ({', '.join(names) or 'none'}) match no signature: expected {expected} "
            "(docs/onnx-models.md)",
        )
    for vi in inputs:
        _check_tensor_io(vi, SIGNATURES[kind][vi.name], "input", name)
    outs = [vi.name for vi in graph.output]
    if outs != [OUTPUT[0]]:
        raise FormatError(
            name, f"outputs ({', '.join(outs) or 'none'}) must be exactly one named '{OUTPUT[0]}'"
        )
    _check_tensor_io(graph.output[0], OUTPUT[1], "output", name)
    return kind


def _check_structure(model: Any, name: str) -> None:
    import onnx

    for op in model.opset_import:
        if op.domain not in _DEFAULT_DOMAINS:
            raise FormatError(
                name, f"custom operator domain '{op.domain}' is not allowed (only ai.onnx)"
            )
        lo, hi = OPSET_RANGE
        if not lo <= op.version <= hi:
            raise FormatError(name, f"opset {op.version} is outside the supported {lo}..{hi}")
    if not any(op.domain in _DEFAULT_DOMAINS for op in model.opset_import):
        raise FormatError(name, "no ai.onnx opset import")
    if len(model.functions):
        raise FormatError(name, "model-local functions are not allowed")
    if len(model.training_info):
        raise FormatError(name, "training info is not allowed")
    graph = model.graph
    if len(graph.sparse_initializer):
        raise FormatError(name, "sparse initialisers are not allowed")
    if len(graph.node) > MAX_NODES:
        raise FormatError(name, f"{len(graph.node)} nodes, more than the limit of {MAX_NODES}")
    total = 0
    for t in graph.initializer:
        total += _tensor_bytes(t, f"initialiser '{t.name}'", name)
    shape_outputs = {o for n in graph.node if n.op_type == "Shape" for o in n.output}
    for node in graph.node:
        label = f"node '{node.name or node.op_type}'"
        if node.domain not in _DEFAULT_DOMAINS:
            raise FormatError(
                name, f"{label} uses custom domain '{node.domain}' (op {node.op_type})"
            )
        if node.op_type not in ALLOWED_OPS:
            raise FormatError(
                name,
                f"{label}: operator {node.op_type} is not allowed "
                "(see the allowlist in docs/onnx-models.md)",
            )
        at = SHAPED_OPS.get(node.op_type)
        if at is not None and (len(node.input) <= at or node.input[at] not in shape_outputs):
            raise FormatError(
                name,
                f"{label}: {node.op_type}'s shape must come straight from a Shape node "
                "(a constant or computed shape could ask for any amount of memory)",
            )
        for attr in node.attribute:
            if attr.type in (onnx.AttributeProto.GRAPH, onnx.AttributeProto.GRAPHS):
                raise FormatError(name, f"{label} has a subgraph attribute '{attr.name}'")
            if attr.type == onnx.AttributeProto.TENSOR:
                total += _tensor_bytes(attr.t, f"{label} attribute '{attr.name}'", name)
            if attr.type == onnx.AttributeProto.SPARSE_TENSOR:
                raise FormatError(name, f"{label} has a sparse tensor attribute")
        if total > MAX_INITIALIZER_BYTES:
            break
    if total > MAX_INITIALIZER_BYTES:
        raise TooLargeError(
            f"{name}: initialisers declare {_mib(total)} in all, over the limit of "
            f"{_mib(MAX_INITIALIZER_BYTES)}"
        )


@dataclass(frozen=True)
class BatchCost:
    """What shape inference with a symbolic batch ``N`` tells of a graph's intermediate
    tensors (every node output): ``row_bytes``, the bytes of those whose size is ``N``
    times a fixed number, per row; ``fixed_bytes``, the bytes of those of a fixed size
    (``Constant`` values not counted: they are initialiser bytes); ``unknown``, the
    tensors whose size inference could not tell (then only the memory limit of the job
    bounds them)."""

    row_bytes: int
    fixed_bytes: int
    unknown: tuple[str, ...]


def _symbolic_copy(model: Any) -> Any:
    """A copy of ``model`` for shape inference: every graph input's first dimension the one
    symbol :data:`BATCH` (all inputs share the batch), and nothing of the file's own
    ``value_info`` or output shapes (a file could declare small shapes for big tensors)."""
    import onnx

    copy = onnx.ModelProto()
    copy.CopyFrom(model)
    graph = copy.graph
    init_names = {t.name for t in graph.initializer}
    for vi in graph.input:
        dims = vi.type.tensor_type.shape.dim
        if vi.name not in init_names and len(dims):
            dims[0].Clear()
            dims[0].dim_param = BATCH
    del graph.value_info[:]
    for vi in graph.output:
        vi.type.tensor_type.ClearField("shape")
    return copy


def _shown(dims: list[Any]) -> str:
    return "[" + ", ".join("?" if d is None else str(d) for d in dims) + "]"


def batch_cost(model: Any, name: str) -> BatchCost:
    """Shape inference of ``model`` with a symbolic batch ``N`` (:data:`BATCH`) on every
    input; refuses, naming the node, what would take memory out of proportion to the file
    or the batch:

    - a node output whose size grows faster than ``N`` (``N`` in two or more dimensions,
      as ``[N, 1] + [1, N]`` gives ``[N, N]``): :class:`FormatError`;
    - a tensor of a fixed size over :data:`MAX_INITIALIZER_BYTES`, or fixed-size tensors
      over it in all; in particular a value computed from initialisers and constants only,
      which onnxruntime folds when it opens the model: :class:`TooLargeError`;
    - a value computed from initialisers and constants only whose shape cannot be told;
    - rows that need more than :data:`MAX_ROW_BYTES` of intermediates each, and an output
      ``rgb`` computed with a fixed last dimension other than 3.
    """
    import onnx

    try:
        inferred = onnx.shape_inference.infer_shapes(
            _symbolic_copy(model), strict_mode=True, data_prop=True
        )
    except (onnx.shape_inference.InferenceError, onnx.checker.ValidationError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FormatError(name, f"invalid ONNX graph: {first[:300]}") from None
    graph = inferred.graph
    shapes = {vi.name: _inferred_dims(vi) for vi in (*graph.value_info, *graph.output)}
    constant = {t.name for t in graph.initializer}
    row_bytes = fixed_bytes = 0
    unknown: list[str] = []
    for node in graph.node:
        label = f"node '{node.name or node.op_type}' ({node.op_type})"
        inputs = [i for i in node.input if i]
        folded = node.op_type == "Constant" or (bool(inputs) and constant.issuperset(inputs))
        for out in (o for o in node.output if o):
            if folded:
                constant.add(out)
            elem, found = shapes.get(out, (-1, None))
            dims = found or []
            itemsize = _ITEMSIZE.get(elem, 8)
            known = found is not None and all(d is not None for d in found)
            if node.op_type == "Constant":
                continue  # counted with the initialisers
            if folded and not (known and all(isinstance(d, int) for d in dims)):
                raise FormatError(
                    name,
                    f"{label} computes '{out}' from initialisers and constants only, but its "
                    "shape cannot be inferred; onnxruntime would fold it when it opens the "
                    "model, at any size",
                )
            grows = sum(1 for d in dims if d == BATCH)
            if grows >= 2:
                raise FormatError(
                    name,
                    f"{label} makes '{out}' of shape {_shown(dims)}: it grows faster than the "
                    f"batch N (N^{grows} elements for N rows); every tensor may grow at most "
                    "linearly with N",
                )
            if not known or any(isinstance(d, str) and d != BATCH for d in dims):
                unknown.append(out)
                continue
            size = itemsize * math.prod(d for d in dims if isinstance(d, int))
            if grows == 1:
                row_bytes += size
                continue
            if size > MAX_INITIALIZER_BYTES:
                source = "from initialisers and constants only" if folded else "of fixed size"
                when = " (onnxruntime computes it when it opens the model)" if folded else ""
                raise TooLargeError(
                    f"{name}: {label} computes '{out}' {_shown(dims)} {source}: "
                    f"{_mib(size)}, over the limit of {_mib(MAX_INITIALIZER_BYTES)} for "
                    f"initialisers{when}"
                )
            fixed_bytes += size
            if fixed_bytes > MAX_INITIALIZER_BYTES:
                raise TooLargeError(
                    f"{name}: the tensors of fixed size up to {label} take "
                    f"{_mib(fixed_bytes)} in all, over the limit of "
                    f"{_mib(MAX_INITIALIZER_BYTES)} for initialisers"
                )
    if row_bytes > MAX_ROW_BYTES:
        raise TooLargeError(
            f"{name}: one row needs {_mib(row_bytes)} of intermediate tensors, over the "
            f"limit of {_mib(MAX_ROW_BYTES)}"
        )
    dims = shapes.get(OUTPUT[0], (-1, None))[1] or []
    if len(dims) == 2 and isinstance(dims[1], int) and dims[1] != OUTPUT[1]:
        raise FormatError(
            name,
            f"output '{OUTPUT[0]}' is computed with shape [N, {dims[1]}]; the signature "
            f"needs [N, {OUTPUT[1]}]",
        )
    return BatchCost(row_bytes, fixed_bytes, tuple(unknown))


def check_onnx_model(model: Any, name: str) -> str:
    """All of :func:`validate_onnx`'s checks on a parsed ``ModelProto``; returns its kind."""
    import onnx

    _check_structure(model, name)
    kind = onnx_kind(model, name)
    try:
        onnx.checker.check_model(model, full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FormatError(name, f"invalid ONNX graph: {first[:300]}") from None
    batch_cost(model, name)
    return kind


def validate_onnx(path: Path, name: str) -> None:
    """Validate a user's ``.onnx`` file (see the module docstring for what is refused)."""
    check_onnx_model(load_onnx_proto(path, name), name)


def check_onnx_file(path: Path, name: str, kind: str) -> None:
    """:func:`validate_onnx`, and its signature is ``kind``'s (``FormatError`` otherwise)."""
    if kind not in SIGNATURES:
        raise ValueError(f"kind must be one of {sorted(SIGNATURES)}, not {kind!r}")
    found = check_onnx_model(load_onnx_proto(path, name), name)
    if found != kind:
        sig = ", ".join(SIGNATURES[kind])
        raise FormatError(
            name, f"declared kind '{kind}' needs inputs ({sig}), but the model is a {found} model"
        )
