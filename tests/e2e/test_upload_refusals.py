"""Uploads that used to answer 500 are refused with a status that names the member.

- a ``.btf.zip`` whose PNG member's header claims 100000 x 100000 pixels (a 300-byte file):
  Pillow's decompression-bomb guard raised while the header was read, and the upload
  answered ``500 internal error: DecompressionBombError``. Now the header is read without
  Pillow, and the archive is over ``MATFORGE_ARCHIVE_MPIX``: 413 naming the member and its
  size. Under a cap raised past it, the image is still over what a slice reader decodes:
  422 naming the member.
- an ``.npz`` with a member that is not a ``.npy`` array: ``np.load`` handed its raw bytes
  to the reader (``500 AttributeError: 'bytes' object has no attribute 'dtype'``). Now
  422 naming the member.
"""

from __future__ import annotations

import io
import struct
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from storage.errors import FormatError
from storage.formats import validate_file
from storage.formats.png import png_size

OCTETS = {"content-type": "application/octet-stream"}


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def huge_png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` 8-bit RGB pixels, with one tiny IDAT."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\0" * 64)
    return (
        b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", idat) + _chunk(b"IEND", b"")
    )


def bomb_archive() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("slices/big.png", huge_png_header(100_000, 100_000))
        zf.writestr("angles.csv", "file,theta_i,phi_i,theta_o,phi_o\nslices/big.png,0,0,10,0\n")
    return buf.getvalue()


def npz_with_text_member() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        entry = io.BytesIO()
        np.lib.format.write_array(entry, np.zeros(3, np.float32))
        zf.writestr("x.npy", entry.getvalue())
        zf.writestr("notes.txt", b"not an array")
    return buf.getvalue()


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path / "data")
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def test01_png_size_reads_the_header_without_pillows_guard(tmp_path: Path) -> None:
    p = tmp_path / "big.png"
    p.write_bytes(huge_png_header(100_000, 100_000))
    assert png_size(p, "big.png") == (100_000, 100_000)
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IEND", b""))
    with pytest.raises(FormatError, match="big.png: unreadable PNG header"):
        png_size(p, "big.png")


def test02_a_bomb_member_is_413_naming_it_and_its_size(client: TestClient) -> None:
    data = bomb_archive()
    assert len(data) < 1024
    r = client.post("/api/artifacts?name=bomb.btf.zip", content=data, headers=OCTETS)
    assert r.status_code == 413, r.text
    err = r.json()["error"]
    assert err.startswith("bomb.btf.zip: slices/big.png: "), err
    assert "100000x100000 pixels" in err and "10000000000 pixels" in err, err


def test03_under_a_raised_cap_the_member_is_still_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "bomb.btf.zip"
    path.write_bytes(bomb_archive())
    with pytest.raises(FormatError) as err:
        validate_file(path, "bomb.btf.zip", max_archive_pixels=10**12)
    msg = str(err.value)
    assert msg.startswith("bomb.btf.zip: slices/big.png: image of 100000x100000 pixels"), msg


def test04_an_npz_member_that_is_not_an_array_is_422_naming_it(client: TestClient) -> None:
    r = client.post("/api/artifacts?name=mixed.npz", content=npz_with_text_member(), headers=OCTETS)
    assert r.status_code == 422, r.text
    err = r.json()["error"]
    assert err.startswith("mixed.npz: member 'notes.txt' is not a .npy array"), err
