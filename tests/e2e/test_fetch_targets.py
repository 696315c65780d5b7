"""What ``matforge fetch -o PATH`` may write (issue 21, items 4 and 12; symbolic links).

``fetch`` used to rename its temporary file over whatever PATH was: as root, ``-o /dev/null``
turned the device into a regular file. Now a FIFO (or a terminal) is written in place once
the bytes are verified, a socket is refused with exit 2, and a regular file is replaced
atomically. A corrupt object writes nothing, to a file, a FIFO or stdout (``-o -``).
A symbolic link is never written through nor replaced, except that a link to a FIFO (or a
terminal) is written in place: a planted ``x.png -> ~/.bashrc`` used to have the file it
names replaced, and a dangling link had its target created; both are refused, exit 2.

Never tested against ``/dev/null`` or any other device: a FIFO in a temporary directory
stands in for one (a failing run can only break the test's own FIFO).
"""

from __future__ import annotations

import hashlib
import os
import socket
import stat
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from storage.formats.png import write_png

from .harness import Server, base_env, matforge_exe, run_cli

TIMEOUT_S = 60.0


def _png(path: Path, value: int) -> Path:
    path.write_bytes(write_png(None, np.full((6, 7, 3), value, np.uint8)))
    return path


@pytest.fixture(scope="module")
def local(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str, bytes]:
    """A data directory holding one imported PNG: ``(data_dir, ref, bytes)``."""
    root = tmp_path_factory.mktemp("fetch-local")
    src = _png(root / "a.png", 9)
    res = run_cli("import", str(src), "--data-dir", str(root / "d"), env=base_env())
    assert res.returncode == 0, res
    return root / "d", res.stdout.strip(), src.read_bytes()


class FifoReader:
    """Reads a FIFO to its end in a thread (opening it blocks until a writer comes)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.data: bytes | None = None
        # daemon: if a broken fetch renamed a file over the FIFO, nobody will ever open it
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        with open(self.path, "rb") as fh:
            self.data = fh.read()

    def finish(self) -> bytes | None:
        """What was read; a reader still waiting for a writer is released (reads nothing)."""
        if self.thread.is_alive() and stat.S_ISFIFO(os.stat(self.path).st_mode):
            try:  # a writer that writes nothing: the reader sees the end of the file
                os.close(os.open(self.path, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass  # the reader is gone already (ENXIO)
        self.thread.join(10)
        return self.data


@pytest.fixture
def fifo(tmp_path: Path) -> Iterator[Path]:
    path = tmp_path / "pipe"
    os.mkfifo(path)
    yield path


def _fetch(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[bytes]:
    return subprocess.run(
        [matforge_exe(), "fetch", *args], env=env, capture_output=True, timeout=TIMEOUT_S
    )


def test01_fifo_is_written_in_place_local(local: tuple[Path, str, bytes], fifo: Path) -> None:
    data_dir, ref, data = local
    reader = FifoReader(fifo)
    proc = _fetch(ref, "-o", str(fifo), "--data-dir", str(data_dir), env=base_env())
    got = reader.finish()
    assert proc.returncode == 0, proc.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode), "the FIFO was replaced by a regular file"
    assert got == data


def test02_fifo_is_written_in_place_from_a_server(server: Server, fifo: Path) -> None:
    src = _png(fifo.parent / "b.png", 3)
    res = run_cli("import", str(src), env=server.env())
    assert res.returncode == 0, res
    reader = FifoReader(fifo)
    proc = _fetch(res.stdout.strip(), "-o", str(fifo), env=server.env())
    got = reader.finish()
    assert proc.returncode == 0, proc.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode), "the FIFO was replaced by a regular file"
    assert got == src.read_bytes()


def test03_a_link_to_a_fifo_is_followed(
    local: tuple[Path, str, bytes], fifo: Path, tmp_path: Path
) -> None:
    data_dir, ref, data = local
    link = tmp_path / "link"
    link.symlink_to(fifo)
    reader = FifoReader(fifo)
    proc = _fetch(ref, "-o", str(link), "--data-dir", str(data_dir), env=base_env())
    got = reader.finish()
    assert proc.returncode == 0, proc.stderr
    assert link.is_symlink() and stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert got == data


def test04_a_socket_is_refused_with_exit_2(local: tuple[Path, str, bytes], tmp_path: Path) -> None:
    data_dir, ref, _ = local
    path = tmp_path / "sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.bind(str(path))
        proc = _fetch(ref, "-o", str(path), "--data-dir", str(data_dir), env=base_env())
        assert proc.returncode == 2, proc.stderr
        assert b"socket" in proc.stderr and str(path).encode() in proc.stderr, proc.stderr
        assert stat.S_ISSOCK(os.stat(path).st_mode), "the socket was replaced"


def test05_regular_files_are_replaced_atomically(
    local: tuple[Path, str, bytes], tmp_path: Path
) -> None:
    data_dir, ref, data = local
    new = tmp_path / "sub" / "new.png"
    old = tmp_path / "old.png"
    old.write_bytes(b"previous contents")
    for out in (new, old):
        proc = _fetch(ref, "-o", str(out), "--data-dir", str(data_dir), env=base_env())
        assert proc.returncode == 0, proc.stderr
        assert out.read_bytes() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.png", "sub"]  # no temp left


def _corrupt_copy(root: Path) -> tuple[Path, str]:
    """A data directory whose one object's bytes are damaged: ``(data_dir, ref)``."""
    res = run_cli("import", str(_png(root / "c.png", 200)), "--data-dir", str(root / "d"),
                  env=base_env())  # fmt: skip
    assert res.returncode == 0, res
    digest = res.stdout.strip().removeprefix("sha256:")
    obj = root / "d" / "store" / "objects" / digest[:2] / digest[2:]
    os.chmod(obj, 0o644)
    obj.write_bytes(b"damaged bytes, not a PNG")
    return root / "d", res.stdout.strip()


def test06_corrupt_object_writes_nothing_to_stdout(tmp_path: Path) -> None:
    data_dir, ref = _corrupt_copy(tmp_path)
    proc = _fetch(ref, "-o", "-", "--data-dir", str(data_dir), env=base_env())
    assert proc.returncode == 1, proc.stderr
    assert b"corrupt" in proc.stderr
    assert proc.stdout == b"", "unverified bytes reached stdout"


def test07_corrupt_object_writes_nothing_to_a_fifo(tmp_path: Path, fifo: Path) -> None:
    data_dir, ref = _corrupt_copy(tmp_path)
    reader = FifoReader(fifo)
    proc = _fetch(ref, "-o", str(fifo), "--data-dir", str(data_dir), env=base_env())
    got = reader.finish()
    assert proc.returncode == 1, proc.stderr
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert got == b"", "unverified bytes reached the FIFO"


def test08_stdout_gets_verified_bytes(local: tuple[Path, str, bytes]) -> None:
    data_dir, ref, data = local
    proc = _fetch(ref, "-o", "-", "--data-dir", str(data_dir), env=base_env())
    assert proc.returncode == 0, proc.stderr
    assert hashlib.sha256(proc.stdout).hexdigest() == hashlib.sha256(data).hexdigest()


def test09_a_link_to_a_regular_file_is_refused_with_exit_2(
    local: tuple[Path, str, bytes], tmp_path: Path
) -> None:
    """The planted ``/tmp/x.png -> ~/.bashrc``, in a temporary directory."""
    data_dir, ref, _ = local
    victim = tmp_path / "bashrc"
    victim.write_bytes(b"the user's own file")
    link = tmp_path / "x.png"
    link.symlink_to(victim)
    proc = _fetch(ref, "-o", str(link), "--data-dir", str(data_dir), env=base_env())
    assert proc.returncode == 2, proc.stderr
    assert f"{link}: is a symbolic link to {victim}".encode() in proc.stderr, proc.stderr
    assert victim.read_bytes() == b"the user's own file"
    assert link.is_symlink() and os.readlink(link) == str(victim)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bashrc", "x.png"]  # no temp left


def test10_a_dangling_link_is_refused_and_its_target_not_created(
    local: tuple[Path, str, bytes], tmp_path: Path
) -> None:
    data_dir, ref, _ = local
    target = tmp_path / "not-yet"
    link = tmp_path / "x.png"
    link.symlink_to(target)
    proc = _fetch(ref, "-o", str(link), "--data-dir", str(data_dir), env=base_env())
    assert proc.returncode == 2, proc.stderr
    assert b"a dangling link" in proc.stderr, proc.stderr
    assert not target.exists() and link.is_symlink()
