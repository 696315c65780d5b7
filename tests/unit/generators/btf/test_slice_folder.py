"""``write_slice_folder``: the folder it writes is one :class:`SliceFolder` (the reader of
``import.btf``) opens, with every slice's angles and pixels as given (EXR float32:
lossless), and mismatched counts are refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from generators.btf.slice_folder import write_slice_folder
from storage.formats.btf_folder import SliceFolder


def test_written_folder_reads_back(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    rgb = rng.random((3, 4, 5, 3), dtype=np.float32)
    angles = [[0.0, 0.0, 0.0, 0.0], [30.0, 40.0, 60.0, 200.0], [75.5, 90.0, 10.0, 0.0]]
    folder = write_slice_folder(tmp_path / "scan", rgb, angles)
    with SliceFolder(folder) as opened:
        assert opened.check_images() == (4, 5)
        assert [list(e.angles()) for e in opened.entries] == angles  # CSV keeps these exactly
        for k, entry in enumerate(opened.entries):
            np.testing.assert_array_equal(opened.read(entry), rgb[k])


def test_counts_must_match(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="2 slice images but 1 angle rows"):
        write_slice_folder(tmp_path / "x", np.zeros((2, 2, 2, 3)), [[0, 0, 0, 0]])
