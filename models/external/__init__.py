"""Users' own material models: read from data files, never code (DESIGN.md, "Plugins").

Two ways in (issue 23):

- the documented MLP formats ``matforge.mlp-brdf/1`` and ``matforge.mlp-btf/1``
  (:mod:`models.external.mlp`, one JSON file; rendered through the fused Dr.Jit kernel,
  :mod:`models.external.fused`);
- an ONNX file: a graph that is an MLP is compiled into the same fused Dr.Jit kernel
  (:mod:`models.external.onnx_mlp`, runtime ``drjit-fused``), any other graph is evaluated
  with onnxruntime (:mod:`models.external.onnx_model`, runtime ``onnxruntime``).

:func:`load_external` dispatches on the file's content, not its name: a JSON object is an
MLP document; a file whose first byte is ``0x08`` (protobuf field 1, ``ir_version``, a
varint: how every ONNX ``ModelProto`` writer starts) is ONNX.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np

from models.external.mlp import MlpMaterial, read_mlp

KINDS = ("brdf", "btf")


@runtime_checkable
class ExternalModel(Protocol):
    """What matforge needs of a user's model, whatever its runtime. The models matforge
    opens also state ``macs_per_eval`` and ``bytes_per_eval`` (:mod:`models.counts`); a
    model without them has its cost document give ``null`` for both."""

    @property
    def kind(self) -> str:
        """``"brdf"`` or ``"btf"``."""
        ...

    @property
    def runtime(self) -> str:
        """Which runtime evaluates it in renders (``"drjit-fused"``, ``"onnxruntime"``)."""
        ...

    @property
    def param_bytes(self) -> int:
        """Bytes of its parameters (float32 counted as 4)."""
        ...

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """``(N, 3)`` values at ``(N, 3)`` directions (and ``(N, 2)`` uv for a BTF)."""
        ...


def model_format(path: Path) -> Literal["mlp", "onnx"]:
    """``"mlp"`` (a JSON document) or ``"onnx"`` (a protobuf ``ModelProto``) from the file's
    first bytes; ``ValueError`` naming the file otherwise."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as exc:
        raise ValueError(f"{Path(path).name}: cannot read ({exc.strerror or exc})") from None
    text = head.lstrip(b" \t\r\n\xef\xbb\xbf")
    if text.startswith(b"{"):
        return "mlp"
    if head[:1] == b"\x08":
        return "onnx"
    raise ValueError(
        f"{Path(path).name}: neither an MLP material (a JSON document, matforge.mlp-brdf/1 or "
        f"matforge.mlp-btf/1) nor an ONNX model"
    )


def load_external(
    path: Path, kind: str, *, label: str | None = None, runtime: str | None = None
) -> ExternalModel:
    """The user's model in ``path`` as a ``kind`` (``"brdf"`` | ``"btf"``) model.

    An ONNX file whose graph is an MLP comes back as an
    :class:`~models.external.onnx_mlp.OnnxMlpMaterial` (fused Dr.Jit kernel), any other as an
    :class:`~models.external.onnx_model.OnnxMaterial` (onnxruntime).

    ``runtime`` (ONNX only): ``"auto"`` (``None``) or ``"onnxruntime"`` (always).

    Raises ``ValueError`` naming the file when it is malformed, of the other kind, or ONNX
    while ONNX support is not installed, or a ``runtime`` given for an MLP file. ``label``
    (the user's ref) names an ONNX model in the messages of its evaluation.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be 'brdf' or 'btf', got {kind!r}")
    name = Path(path).name
    if model_format(Path(path)) == "mlp":
        if runtime is not None:
            raise ValueError(f"{name}: runtime applies to ONNX models, not an MLP file")
        model: Any = read_mlp(path)
        if model.kind != kind:
            raise ValueError(f"{name}: is a {model.kind} model, not a {kind} one")
        return model  # type: ignore[no-any-return,unused-ignore]
    try:
        importlib.import_module("models.external.onnx_model")
        onnx_mlp = importlib.import_module("models.external.onnx_mlp")
    except ImportError as exc:
        raise ValueError(f"{name}: ONNX models are not supported by this build ({exc})") from None
    return onnx_mlp.open_onnx(  # type: ignore[no-any-return,unused-ignore]
        Path(path), kind, runtime=runtime or "auto", label=label
    )


__all__ = ["KINDS", "ExternalModel", "MlpMaterial", "load_external", "model_format", "read_mlp"]
