"""BTF shards and index (:mod:`storage.formats.btf`): a round trip, and malformed files
refused with a message naming the file and what is wrong."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from storage.errors import FormatError
from storage.formats.btf import index_document, iter_shards, parse_index, read_shard, shard_bytes
from storage.formats.npz import npz_bytes

UP = np.array([0.0, 0.0, 1.0])


def _shard(n: int = 2, res: int = 4) -> dict[str, np.ndarray]:
    return {
        "wi": np.tile(UP, (n, 1)).astype(np.float32),
        "wo": np.tile(UP, (n, 1)).astype(np.float32),
        "rgb": np.full((n, res, res, 3), 0.1, np.float32),
        "stderr": np.zeros(n, np.float32),
    }


def test01_round_trip(tmp_path: Path) -> None:
    a = _shard()
    (tmp_path / "slices-0000.npz").write_bytes(shard_bytes(**a, dtype="float16"))
    s = read_shard(tmp_path / "slices-0000.npz")
    assert s.rgb.dtype == np.float16 and len(s) == 2
    doc = index_document((4, 4), [("slices-0000.npz", 2)], spp=4)
    index = parse_index(json.dumps(doc))
    assert index.count == 2 and index.doc["spp"] == 4
    ((first, shard),) = list(iter_shards(index, lambda name: tmp_path / name))
    assert first == 0 and np.allclose(shard.rgb, 0.1, atol=1e-3)


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        ({"rgb": None}, "missing array 'rgb'"),
        ({"wi": np.tile([0.0, 0.0, 2.0], (2, 1))}, "wi must hold unit vectors"),
        ({"wo": np.tile([0.0, 0.0, -1.0], (2, 1))}, "wo must point above the surface"),
        ({"rgb": np.full((2, 4, 4), 0.1)}, "rgb must be float (N, H, W, 3)"),
        ({"rgb": np.full((2, 4, 4, 3), -1.0)}, "negative"),
        ({"stderr": np.zeros(3)}, "stderr must be (2,)"),
    ],
)
def test02_malformed_shards_are_named(tmp_path: Path, change: dict, problem: str) -> None:
    arrays = {**_shard(), **change}
    arrays = {k: v for k, v in arrays.items() if v is not None}
    path = tmp_path / "bad.npz"
    path.write_bytes(npz_bytes(arrays))
    with pytest.raises(FormatError) as err:
        read_shard(path, "slices-0003.npz")
    assert str(err.value).startswith("slices-0003.npz: ") and problem in str(err.value)


def test03_index_checks(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="btf.json: not JSON"):
        parse_index(b"{")
    with pytest.raises(FormatError, match="not a BTF index"):
        parse_index(json.dumps({"format": "other"}))
    doc = index_document((4, 4), [("slices-0000.npz", 3)])
    doc["count"] = 5
    with pytest.raises(FormatError, match="do not add up"):
        parse_index(json.dumps(doc))
    (tmp_path / "slices-0000.npz").write_bytes(shard_bytes(**_shard()))
    index = parse_index(json.dumps(index_document((4, 4), [("slices-0000.npz", 3)])))
    with pytest.raises(FormatError, match="slices-0000.npz: holds 2 slices"):
        list(iter_shards(index, lambda name: tmp_path / name))
