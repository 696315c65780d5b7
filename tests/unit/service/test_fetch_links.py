"""``write_verified`` (what ``matforge fetch -o`` and ``Client.fetch`` write with) never
writes through a symbolic link nor replaces one, in a temporary directory with real links:
a link to a regular file or a dangling one is refused with nothing written; a link to a
FIFO is written in place; the sub-folders a whole job's artifacts go to are never links."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from service.cli.client import BadInput
from service.cli.fetch_output import Write, check_subfolders, write_verified

DATA = b"verified bytes"


def fill(write: Write) -> int:
    write(DATA)
    return len(DATA)


def test01_a_link_to_a_file_is_refused_and_the_file_kept(tmp_path: Path) -> None:
    victim = tmp_path / "bashrc"
    victim.write_bytes(b"mine")
    link = tmp_path / "x.png"
    link.symlink_to(victim)
    with pytest.raises(BadInput, match=r"x.png: is a symbolic link to .*bashrc \(a regular file\)"):
        write_verified(link, fill, mode=0o644)
    assert victim.read_bytes() == b"mine" and link.is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bashrc", "x.png"]


def test02_a_dangling_link_does_not_create_its_target(tmp_path: Path) -> None:
    link = tmp_path / "x.png"
    link.symlink_to(tmp_path / "elsewhere")
    with pytest.raises(BadInput, match="a dangling link"):
        write_verified(link, fill, mode=0o644)
    assert not (tmp_path / "elsewhere").exists() and link.is_symlink()


def test03_a_link_to_a_fifo_is_written_in_place(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    link = tmp_path / "link"
    link.symlink_to(fifo)
    got: list[bytes] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    assert write_verified(link, fill, mode=0o644) == len(DATA)
    reader.join(10)
    assert got == [DATA] and link.is_symlink()


def test04_a_file_and_a_new_path_are_still_written(tmp_path: Path) -> None:
    old = tmp_path / "old.png"
    old.write_bytes(b"previous")
    for out in (old, tmp_path / "sub" / "new.png"):
        assert write_verified(out, fill, mode=0o640) == len(DATA)
        assert out.read_bytes() == DATA and (out.stat().st_mode & 0o777) == 0o640


def test05_a_linked_subfolder_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "run1"
    out.mkdir()
    (tmp_path / "home").mkdir()
    (out / "maps").symlink_to(tmp_path / "home")
    with pytest.raises(BadInput, match=r"run1/maps: is a symbolic link"):
        check_subfolders(out, Path("maps/albedo.exr"))
    check_subfolders(out, Path("other/albedo.exr"))  # not there yet: fetch creates it
    check_subfolders(out, Path("preview.png"))
