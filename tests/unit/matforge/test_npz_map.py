"""``matforge.datasets.npz_map.open_npz``: the members of matforge's stored ``.npz`` files are
memory-mapped at their offsets, other ``.npz`` files still read; ``np.load`` is the oracle."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from matforge.datasets.npz_map import open_npz
from storage.errors import FormatError
from storage.formats.npz import npz_bytes

ARRAYS = {
    "rgb": np.arange(2 * 3 * 4 * 3, dtype=np.float32).reshape(2, 3, 4, 3),
    "fortran": np.asfortranarray(np.arange(12, dtype=np.float64).reshape(3, 4)),
    "scalar": np.array(0.25, np.float32),
    "empty": np.zeros((0, 3), np.float32),
    "ids": np.array([3, 1, 2], np.int32),
}


def test01_stored_members_are_mapped(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    path.write_bytes(npz_bytes(ARRAYS))
    got = open_npz(path)
    assert set(got) == set(ARRAYS)
    assert isinstance(got["rgb"], np.memmap) and not got["rgb"].flags.writeable
    with np.load(path) as ref:
        for k in ARRAYS:
            np.testing.assert_array_equal(got[k], ref[k])
            assert got[k].dtype == ref[k].dtype and got[k].shape == ref[k].shape


def test02_compressed_members_are_read(tmp_path: Path) -> None:
    path = tmp_path / "c.npz"
    np.savez_compressed(path, **ARRAYS)
    got = open_npz(path)
    assert not isinstance(got["rgb"], np.memmap)
    for k, v in ARRAYS.items():
        np.testing.assert_array_equal(got[k], v)


def test03_malformed_files_are_refused_by_name(tmp_path: Path) -> None:
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip at all")
    with pytest.raises(FormatError, match="shard-0001.npz"):
        open_npz(bad, "shard-0001.npz")
    lying = tmp_path / "lying.npz"
    data = bytearray(npz_bytes({"x": np.zeros(4, np.float32)}))
    at = data.index(b"(4,)")
    data[at : at + 4] = b"(9,)"  # the header claims more than the member holds
    lying.write_bytes(bytes(data))
    with pytest.raises(FormatError, match="lying.npz"):  # the CRC or the header check
        open_npz(lying)
