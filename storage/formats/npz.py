"""Dataset shards as ``.npz``: a deterministic writer and a validating reader."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from storage.errors import FormatError

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)
#: The most bytes an ``.npz`` may expand to (all members, decompressed): checked from the
#: zip directory and each array's header before any array is read.
MAX_NPZ_BYTES = 1 << 30


@dataclass(frozen=True)
class StreamedArray:
    """An array written piece by piece by :func:`write_npz`: its ``shape`` and ``dtype``,
    and ``pieces``, C-order blocks along the first axis whose sizes add up to the whole
    (e.g. one image of a stack at a time). Only one piece need be in memory."""

    shape: tuple[int, ...]
    dtype: str
    pieces: Iterable[np.ndarray]


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An uncompressed ``.npz`` (readable by ``np.load``) with fixed zip timestamps, so the
    same arrays always give the same bytes (``np.savez`` stamps entries on some versions)."""
    buf = io.BytesIO()
    write_npz(buf, arrays)
    return buf.getvalue()


def write_npz(fp: BinaryIO, arrays: Mapping[str, np.ndarray | StreamedArray]) -> None:
    """Write :func:`npz_bytes`'s bytes to the seekable binary file ``fp``; a
    :class:`StreamedArray` is written one piece at a time (the same bytes as the whole
    array), so a stack of large images never sits in memory at once."""
    with zipfile.ZipFile(fp, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_DATE)
            if not isinstance(arr, StreamedArray):
                entry = io.BytesIO()
                # np.asarray(order="C"), not np.ascontiguousarray, which turns scalars
                # into (1,).
                np.lib.format.write_array(entry, np.asarray(arr, order="C"), allow_pickle=False)
                zf.writestr(info, entry.getvalue())
                continue
            dtype = np.dtype(arr.dtype)
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(
                header,
                {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                 "shape": tuple(arr.shape)},
            )  # fmt: skip
            data_size = int(np.prod(arr.shape, dtype=np.int64)) * dtype.itemsize
            # The size up front, as writestr sets it: the same zip64 choice, the same bytes.
            info.file_size = header.tell() + data_size
            written = 0
            with zf.open(info, "w") as dest:
                dest.write(header.getvalue())
                for piece in arr.pieces:
                    block = np.ascontiguousarray(piece, dtype=dtype)
                    dest.write(block.data.cast("B"))
                    written += block.nbytes
            if written != data_size:
                raise ValueError(
                    f"array {name!r}: its pieces hold {written} bytes, not the {data_size} "
                    f"of shape {tuple(arr.shape)} {dtype}"
                )


def check_npz_headers(path: Path, label: str, max_bytes: int = MAX_NPZ_BYTES) -> None:
    """Refuse an ``.npz`` from its headers alone: members that decompress to more than
    ``max_bytes`` in all, a member that is not a ``.npy`` array (``np.load`` would hand its
    raw bytes to the reader), or an array whose header (shape x itemsize) disagrees with
    the member's size, e.g. a header claiming ``(2**40,)`` elements. Nothing large is
    read."""
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            total = sum(i.file_size for i in infos)
            if total > max_bytes:
                raise FormatError(
                    label,
                    f"its arrays decompress to {total} bytes, over the limit of {max_bytes} bytes",
                )
            for info in infos:
                if not info.filename.endswith(".npy"):
                    raise FormatError(
                        label,
                        f"member {info.filename!r} is not a .npy array (an .npz holds only "
                        f"arrays, each a '<name>.npy' member)",
                    )
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
                    else:
                        raise FormatError(label, f"array {info.filename!r}: .npy {version}")
                    header = fh.tell()
                if dtype.hasobject:
                    raise FormatError(label, f"array {info.filename!r} holds Python objects")
                claimed = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if claimed != info.file_size - header:
                    raise FormatError(
                        label,
                        f"array {info.filename!r}: its header claims shape {tuple(shape)} of "
                        f"{dtype} ({claimed} bytes) but it holds {info.file_size - header} bytes",
                    )
    except FormatError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError, RuntimeError) as exc:
        raise FormatError(label, f"not a readable .npz archive: {exc}") from None


def read_npz(
    path: Path, name: str | None = None, *, nan_ok: tuple[str, ...] = ()
) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` (no pickled objects); ``FormatError`` naming the file if it is
    not a readable npz or holds non-finite floats (NaN allowed in the arrays ``nan_ok``
    names, where it means "unknown"; infinity never)."""
    label = name or str(path)
    if not zipfile.is_zipfile(path):
        raise FormatError(label, "not a .npz archive (no zip structure)")
    check_npz_headers(Path(path), label)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise FormatError(label, f"not a readable .npz archive: {exc}") from None
    for key, arr in arrays.items():
        if key in nan_ok and arr.dtype.kind == "f" and not np.any(np.isinf(arr)):
            continue
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise FormatError(label, f"array {key!r} has non-finite values (NaN or infinity)")
    return arrays


def validate_npz(path: Path, name: str | None = None) -> None:
    """Validator for ``storage.formats.validate_file``."""
    read_npz(path, name)
