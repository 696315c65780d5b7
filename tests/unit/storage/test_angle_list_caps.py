"""A slice folder's angle list is read with a bounded size and entry count, by the one
reader the upload check and ``import.btf`` share (:class:`SliceFolder`): each refusal names
the archive and the list, and none reads the list whole first."""

from __future__ import annotations

import zipfile
from pathlib import Path

import pytest

from storage.errors import FormatError
from storage.formats.btf_folder import MAX_LIST_BYTES, MAX_SLICES, SliceFolder

HEADER = "file,theta_i,phi_i,theta_o,phi_o\n"


def _zip(path: Path, name: str, text: str) -> Path:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(name, text)
    return path


def test01_a_list_over_the_byte_limit_is_refused_from_the_zip_directory(tmp_path: Path) -> None:
    z = _zip(tmp_path / "big.btf.zip", "angles.csv", HEADER + " " * MAX_LIST_BYTES)
    size = len(HEADER) + MAX_LIST_BYTES
    with pytest.raises(FormatError, match=rf"big.btf.zip: angles.csv: holds {size} bytes, over"):
        SliceFolder(z, "big.btf.zip")


def test02_a_json_list_of_empty_lists_is_refused_before_parsing(tmp_path: Path) -> None:
    text = "[" + ",".join(["[]"] * (MAX_SLICES + 2)) + "]"
    z = _zip(tmp_path / "lists.btf.zip", "angles.json", text)
    with pytest.raises(FormatError, match=r"lists.btf.zip: angles.json: has \d+ JSON objects"):
        SliceFolder(z, "lists.btf.zip")


def test03_a_field_over_the_csv_limit_is_a_format_error(tmp_path: Path) -> None:
    """A 200 KB quoted field: ``csv`` raises its own error past 128 KB, which used to
    escape as a 500."""
    z = _zip(tmp_path / "long.btf.zip", "angles.csv", HEADER + '"' + "a" * 200_000 + '",0,0,0,0\n')
    with pytest.raises(FormatError, match=r"long.btf.zip: angles.csv: line \d+: field larger"):
        SliceFolder(z, "long.btf.zip")


def test04_a_list_that_is_not_utf8_is_a_format_error(tmp_path: Path) -> None:
    with zipfile.ZipFile(tmp_path / "bin.btf.zip", "w") as zf:
        zf.writestr("angles.csv", HEADER.encode() + b"\xff\xfe,0,0,0,0\n")
    with pytest.raises(FormatError, match=r"bin.btf.zip: angles.csv: is not UTF-8 text"):
        SliceFolder(tmp_path / "bin.btf.zip", "bin.btf.zip")
