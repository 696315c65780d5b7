"""Uploads are validated in a bounded child process, never in the web process, and refused
with a message over the caps (issue 15, B3)."""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from service.upload_check import UploadChecker
from storage.errors import FormatError, TooLargeError
from storage.formats.exr import exr_bytes

OCTETS = {"content-type": "application/octet-stream"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def _zeros_npz(n: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        entry = io.BytesIO()
        np.lib.format.write_array(entry, np.zeros(n, np.float64))
        zf.writestr("z.npy", entry.getvalue())
    return buf.getvalue()


def test01_lying_npz_header_is_422_not_500(client: TestClient) -> None:
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<f8", "fortran_order": False, "shape": (2**40,)}
    )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("x.npy", header.getvalue() + b"\0" * 64)
    r = client.post("/api/artifacts?name=claims.npz", content=buf.getvalue(), headers=OCTETS)
    assert r.status_code == 422, r.text
    assert r.json()["error"].startswith("claims.npz: array 'x.npy': its header claims")


def test02_valid_upload_still_works(client: TestClient) -> None:
    r = client.post(
        "/api/artifacts?name=ok.exr", content=exr_bytes(np.ones((4, 4, 3))), headers=OCTETS
    )
    assert r.status_code == 201, r.text
    bad = client.post("/api/artifacts?name=bad.exr", content=b"v/1\x01" + b"\0" * 64)
    assert bad.status_code == 422 and bad.json()["error"].startswith("bad.exr: ")


def test03_decoding_runs_in_a_bounded_child(tmp_path: Path) -> None:
    """A deflated npz of zeros (a few hundred KB) that decodes to 240 MB: out of memory in
    the child (capped at 200 MB here) is a 413-type error; the next file gets a fresh child,
    and the caller's process never decodes."""
    bomb = tmp_path / "bomb.npz"
    bomb.write_bytes(_zeros_npz(30_000_000))
    assert bomb.stat().st_size < 1_000_000
    good = tmp_path / "good.exr"
    good.write_bytes(exr_bytes(np.ones((4, 4, 3))))
    checker = UploadChecker(max_bytes=200 * 1024 * 1024)
    try:
        with pytest.raises((TooLargeError, FormatError)) as info:
            checker.validate(bomb, "bomb.npz")
        assert str(info.value).startswith("bomb.npz: ")
        assert checker.validate(good, "good.exr") == "image/x-exr"
        pool = checker._pool
        assert pool is not None
        assert os.getpid() not in {p.pid for p in pool._processes.values()}  # type: ignore[attr-defined]
    finally:
        checker.close()
