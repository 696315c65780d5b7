"""Arrays of an ``.npz`` file opened lazily, memory-mapped where possible.

matforge writes its shards as uncompressed zip archives of ``.npy`` members
(:func:`storage.formats.npz.npz_bytes`), so each array is a contiguous run of bytes in the
file: :func:`open_npz` maps it (``numpy.memmap``, read-only) at its offset instead of
reading it. A compressed member (an ``.npz`` written by someone else with
``np.savez_compressed``) is read into memory instead. Headers are checked first
(:func:`storage.formats.npz.check_npz_headers`): nothing is mapped whose header disagrees
with the member's size, and no pickled objects are ever loaded.
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

import numpy as np

from storage.errors import FormatError
from storage.formats.npz import check_npz_headers

#: Size of a zip local file header before its name and extra field (PKWARE APPNOTE 4.3.7).
_LOCAL_HEADER = 30
_LOCAL_MAGIC = b"PK\x03\x04"


def _member(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo, label: str) -> np.ndarray:
    if info.compress_type != zipfile.ZIP_STORED:
        with zf.open(info) as fh:
            return np.asarray(np.lib.format.read_array(fh, allow_pickle=False))
    with open(path, "rb") as raw:
        raw.seek(info.header_offset)
        head = raw.read(_LOCAL_HEADER)
        if len(head) != _LOCAL_HEADER or head[:4] != _LOCAL_MAGIC:
            raise FormatError(label, f"member {info.filename!r}: bad zip local header")
        name_len, extra_len = struct.unpack("<HH", head[26:30])
        start = info.header_offset + _LOCAL_HEADER + name_len + extra_len
        raw.seek(start)
        version = np.lib.format.read_magic(raw)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(raw)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(raw)
        offset = raw.tell()
    if int(np.prod(shape, dtype=np.int64)) == 0:
        return np.zeros(shape, dtype)
    return np.memmap(
        path,
        dtype=dtype,
        mode="r",
        offset=offset,
        shape=tuple(shape),
        order="F" if fortran else "C",
    )


def open_npz(path: str | Path, label: str | None = None) -> dict[str, np.ndarray]:
    """Every array of the ``.npz`` at ``path`` by name (without ``.npy``): read-only memory
    maps for stored members, in-memory arrays for compressed ones. ``FormatError`` naming
    ``label`` (default: the path) for anything that is not a well-formed ``.npz``."""
    p = Path(path)
    name = label or str(p)
    check_npz_headers(p, name, max_bytes=1 << 62)
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(p) as zf:
            for info in zf.infolist():
                if info.filename.endswith(".npy"):
                    out[info.filename[:-4]] = _member(p, zf, info, name)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise FormatError(name, f"not a readable .npz archive: {exc}") from None
    return out
