"""Readers refuse what their headers show to be too big, before decoding (issue 15, B3)."""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest

from storage.errors import FormatError
from storage.formats import exr, png
from storage.formats.npz import check_npz_headers, npz_bytes, read_npz


def _lying_npz(path: Path, shape: tuple[int, ...]) -> Path:
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": shape}
    )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("x.npy", header.getvalue() + b"\0" * 64)
    path.write_bytes(buf.getvalue())
    return path


def test01_npz_header_claiming_2_to_the_40_is_refused(tmp_path: Path) -> None:
    p = _lying_npz(tmp_path / "liar.npz", (2**40,))
    with pytest.raises(FormatError, match=r"liar.npz: array 'x.npy': its header claims shape"):
        read_npz(p, "liar.npz")


def test02_npz_decompressed_size_is_capped(tmp_path: Path) -> None:
    p = tmp_path / "zeros.npz"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        entry = io.BytesIO()
        np.lib.format.write_array(entry, np.zeros(100_000))
        zf.writestr("z.npy", entry.getvalue())
    p.write_bytes(buf.getvalue())
    assert p.stat().st_size < 10_000
    with pytest.raises(FormatError, match="decompress to 800128 bytes, over the limit of 100000"):
        check_npz_headers(p, "zeros.npz", max_bytes=100_000)
    check_npz_headers(p, "zeros.npz")  # under the default cap
    good = tmp_path / "good.npz"
    good.write_bytes(npz_bytes({"a": np.ones((2, 3), np.float32), "s": np.float32(1)}))
    assert set(read_npz(good)) == {"a", "s"}


def test03_pixel_caps_from_the_header(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    e = tmp_path / "a.exr"
    exr.write_exr(e, np.zeros((16, 16, 3), np.float32))
    p = tmp_path / "a.png"
    png.write_png(p, np.zeros((16, 16, 3), np.uint8))
    monkeypatch.setattr(exr, "MAX_PIXELS", 255)
    monkeypatch.setattr(png, "MAX_PIXELS", 255)
    with pytest.raises(FormatError, match="16x16 pixels exceeds the limit of 255 pixels"):
        exr.validate_exr(e, "a.exr")
    with pytest.raises(FormatError, match="16x16 pixels exceeds the limit of 255 pixels"):
        png.validate_png(p, "a.png")


def test04_format_error_crosses_processes() -> None:
    err = pickle.loads(pickle.dumps(FormatError("a.exr", "broken")))
    assert isinstance(err, FormatError) and (err.filename, err.problem) == ("a.exr", "broken")
    assert str(err) == "a.exr: broken"
