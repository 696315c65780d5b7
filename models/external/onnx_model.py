"""A user's ONNX material model, evaluated with onnxruntime on numpy batches.

The signature is documented in ``docs/onnx-models.md`` and checked by
:mod:`storage.formats.onnx`: a ``brdf`` takes ``wi``, ``wo`` ``(N, 3)`` float32 (local
frame, z up) and returns ``rgb`` ``(N, 3)``, the plain BRDF in 1/sr without cosine; a
``btf`` also takes ``uv`` ``(N, 2)`` (patch coordinates) and returns the BTF in
``generate.btf``'s convention (``L_o / E_perp``: ``cos(theta_i)`` of the light ``wi``
included).

The session is fixed so that the same inputs give the same bytes on a machine: the CPU
provider only, ``intra_op_num_threads`` set (default :data:`DEFAULT_THREADS`), one
inter-op thread, sequential execution, deterministic compute, and no spinning between
calls (the renderer's threads share the cores between two calls). Batches are cut into
chunks (:func:`chunk_rows`) so that the intermediate tensors of one call stay within
:data:`CALL_BYTES` whatever ``N``: shape inference with a symbolic batch
(:func:`storage.formats.onnx.batch_cost`) gives their bytes per row.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from storage.formats.onnx import BatchCost, batch_cost, check_onnx_file, load_onnx_proto

#: onnxruntime intra-op threads (the renders' machines have 2 cores per job).
DEFAULT_THREADS = 2
#: The most rows per onnxruntime call.
CHUNK = 1 << 18
#: The bytes of intermediate tensors one call may make, summed over all of them (an upper
#: bound: onnxruntime reuses buffers): its rows times the graph's bytes per row.
CALL_BYTES = 256 * 1024 * 1024
#: Rows per call of a graph with a tensor whose size shape inference cannot tell: even a
#: hidden ``[N, N]`` float32 tensor is then 64 MiB.
UNKNOWN_SHAPE_CHUNK = 4096
#: The runtime named in cost rows.
RUNTIME = "onnxruntime"


class OnnxEvalError(ValueError):
    """The model failed at evaluation time: onnxruntime refused the batch, or the output is
    not ``[rows, 3]``. The message names the model (:attr:`OnnxMaterial.name`) and what is
    wrong; renders turn it into the job's error."""


@dataclass
class EvalStats:
    """Where the time goes: calls into onnxruntime, rows evaluated, seconds inside it."""

    calls: int = 0
    rows: int = 0
    seconds: float = 0.0

    def reset(self) -> None:
        self.calls, self.rows, self.seconds = 0, 0, 0.0


def _param_bytes(model: Any) -> int:
    """Bytes of the floating-point initialisers and ``Constant`` tensors: the parameters
    (integer tensors, the indices and shapes of slicing and reshaping, are not counted)."""
    from onnx import numpy_helper

    tensors = list(model.graph.initializer)
    tensors += [a.t for n in model.graph.node for a in n.attribute if a.HasField("t")]
    arrays = (numpy_helper.to_array(t) for t in tensors)
    return int(sum(a.nbytes for a in arrays if np.issubdtype(a.dtype, np.floating)))


@dataclass
class OnnxMaterial:
    """An ONNX BRDF or BTF (see the module docstring), ready to evaluate.

    Attributes: ``kind`` (``"brdf"`` or ``"btf"``), ``runtime`` (``"onnxruntime"``),
    ``param_bytes`` (bytes of the floating-point initialisers), ``threads`` (intra-op threads),
    ``stats`` (:class:`EvalStats`), ``name`` (the user's ref or the file's name, for
    messages), ``chunk`` (rows per onnxruntime call).
    """

    kind: str
    param_bytes: int
    threads: int
    name: str
    session: Any = field(repr=False)
    runtime: str = RUNTIME
    stats: EvalStats = field(default_factory=EvalStats)
    #: Rows per onnxruntime call (:func:`chunk_rows`).
    chunk: int = CHUNK
    #: Multiply-adds and bytes read per evaluation, counted from the graph
    #: (:func:`models.external.onnx_mlp.graph_counts`; ``None`` when not counted).
    macs_per_eval: int | None = None
    bytes_per_eval: int | None = None

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """The model at ``N`` direction pairs: ``(N, 3)`` float32 RGB.

        ``wi``, ``wo``: ``(N, 3)`` local unit vectors, z up; ``uv``: ``(N, 2)`` patch
        coordinates, required for a BTF and refused for a BRDF. ``ValueError`` on other
        shapes; the model's values are returned as they are (no horizon mask).
        """
        wi = np.ascontiguousarray(wi, np.float32)
        wo = np.ascontiguousarray(wo, np.float32)
        n = len(wi)
        if wi.shape != (n, 3) or wo.shape != (n, 3):
            raise ValueError(f"wi and wo must be (N, 3), got {wi.shape} and {wo.shape}")
        feeds: dict[str, np.ndarray] = {"wi": wi, "wo": wo}
        if self.kind == "btf":
            if uv is None:
                raise ValueError(f"{self.name}: a BTF model needs uv (N, 2)")
            uv = np.ascontiguousarray(uv, np.float32)
            if uv.shape != (n, 2):
                raise ValueError(f"uv must be (N, 2), got {uv.shape}")
            feeds["uv"] = uv
        elif uv is not None:
            raise ValueError(f"{self.name}: a BRDF model takes no uv")
        out = np.empty((n, 3), np.float32)
        started = time.perf_counter()
        for lo in range(0, n, self.chunk):
            chunk = {k: v[lo : lo + self.chunk] for k, v in feeds.items()}
            rgb = self._run(chunk)
            rows = len(chunk["wi"])
            if rgb.shape != (rows, 3):
                raise OnnxEvalError(
                    f"{self.name}: the model's output rgb has shape {list(rgb.shape)} for "
                    f"{rows} rows; the signature needs [N, 3] (N rows of RGB)"
                )
            out[lo : lo + rows] = rgb
            self.stats.calls += 1
        self.stats.rows += n
        self.stats.seconds += time.perf_counter() - started
        return out

    def _run(self, feeds: dict[str, np.ndarray]) -> np.ndarray:
        """One onnxruntime call; its failures as :class:`OnnxEvalError` naming the model, or
        ``MemoryError`` where it could not allocate (the job's error then says "out of
        memory")."""
        try:
            (rgb,) = self.session.run(["rgb"], feeds)
        except Exception as exc:  # onnxruntime's own exception types (pybind11)
            text = " ".join(str(exc).split())[:300]
            if "alloc" in text.lower():
                raise MemoryError(f"{self.name}: onnxruntime could not allocate: {text}") from None
            raise OnnxEvalError(f"{self.name}: onnxruntime failed on the model: {text}") from None
        return np.asarray(rgb)


def make_session(data: bytes, threads: int) -> Any:
    """An onnxruntime CPU session of the model bytes ``data`` with the fixed options of the
    module docstring."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.use_deterministic_compute = True
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    opts.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return ort.InferenceSession(data, sess_options=opts, providers=["CPUExecutionProvider"])


def chunk_rows(cost: BatchCost) -> int:
    """Rows per onnxruntime call for a graph of ``cost``: as many as keep its intermediate
    tensors within :data:`CALL_BYTES`, at most :data:`CHUNK`, at most
    :data:`UNKNOWN_SHAPE_CHUNK` where some tensor's size is unknown, at least 1."""
    rows = CHUNK if cost.row_bytes <= 0 else CALL_BYTES // cost.row_bytes
    if cost.unknown:
        rows = min(rows, UNKNOWN_SHAPE_CHUNK)
    return max(1, min(CHUNK, rows))


def load_onnx(
    path: Path, kind: str, *, threads: int = DEFAULT_THREADS, label: str | None = None
) -> OnnxMaterial:
    """Validate ``path`` (:func:`storage.formats.onnx.check_onnx_file`: the upload checks
    and the signature of ``kind``) and open it. ``label`` names the model in messages (the
    user's ``sha256:`` or ``job:`` ref; default the file's name).

    Raises :class:`storage.errors.FormatError` (or ``TooLargeError``) naming the model and
    what is wrong, ``ValueError`` for an unknown ``kind`` or ``threads < 1``.
    """
    path = Path(path)
    name = label or path.name
    if threads < 1:
        raise ValueError(f"threads must be >= 1, not {threads}")
    check_onnx_file(path, name, kind)
    model = load_onnx_proto(path, name)
    return OnnxMaterial(
        kind=kind,
        param_bytes=_param_bytes(model),
        threads=threads,
        name=name,
        session=make_session(path.read_bytes(), threads),
        chunk=chunk_rows(batch_cost(model, name)),
    )
