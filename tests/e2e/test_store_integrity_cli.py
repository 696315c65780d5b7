"""Corrupt objects and stale work directories through the CLI (issue 15, B1).

- ``matforge fetch`` of an object whose bytes are damaged on the server exits 1 with the
  message (it used to exit 3, "unreachable");
- ``matforge store verify --repair`` restores an upload from a good copy, or names what it
  cannot repair and exits 1;
- ``matforge store gc`` removes the work directories killed workers left in ``scratch``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from storage.formats.png import write_png

from .harness import Server, base_env, run_cli


def _png(path: Path, value: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(write_png(None, np.full((4, 5, 3), value, np.uint8)))
    return path


def _damage(data_dir: Path, ref: str) -> None:
    d = ref.removeprefix("sha256:")
    p = data_dir / "store" / "objects" / d[:2] / d[2:]
    os.chmod(p, 0o644)
    p.write_bytes(b"damaged")


def test01_fetch_of_a_corrupt_object_exits_1(server: Server, tmp_path: Path) -> None:
    res = run_cli("import", str(_png(tmp_path / "a.png", 7)), env=server.env())
    assert res.returncode == 0, res
    ref = res.stdout.strip()
    _damage(server.data_dir, ref)
    out = tmp_path / "out.png"
    res = run_cli("fetch", ref, "-o", str(out), env=server.env())
    assert res.returncode == 1, res
    assert "corrupt" in res.stderr and ref in res.stderr, res
    assert not out.exists()


def test02_verify_repair_from_a_good_copy(tmp_path: Path) -> None:
    env, data = base_env(), tmp_path / "d"
    good = _png(tmp_path / "originals" / "good.png", 1)
    lost = _png(tmp_path / "elsewhere" / "lost.png", 2)
    refs = []
    for p in (good, lost):
        res = run_cli("import", str(p), "--data-dir", str(data), env=env)
        assert res.returncode == 0, res
        refs.append(res.stdout.strip())
        _damage(data, refs[-1])
    res = run_cli(
        "store", "verify", "--data-dir", str(data), "--repair",
        "--source", str(tmp_path / "originals"), env=env,
    )  # fmt: skip
    assert res.returncode == 1, res  # one of the two could not be repaired
    assert f"repaired {refs[0]}" in res.stdout, res
    assert refs[1] in res.stderr and "not repaired" in res.stderr and "lost.png" in res.stderr
    res = run_cli("store", "verify", "--data-dir", str(data), "--json", env=env)
    assert [c["digest"] for c in res.json()["corrupt"]] == [refs[1].removeprefix("sha256:")]
    res = run_cli(
        "store", "verify", "--data-dir", str(data), "--repair",
        "--source", str(lost), "--json", env=env,
    )  # fmt: skip
    assert res.returncode == 0 and res.json()["ok"] is True, res


def test03_gc_removes_stale_scratch_dirs(tmp_path: Path) -> None:
    env, data = base_env(), tmp_path / "d"
    res = run_cli("import", str(_png(tmp_path / "a.png", 3)), "--data-dir", str(data), env=env)
    assert res.returncode == 0, res
    stale = data / "scratch" / "job-0123abcd-999999-q1w2"
    (stale / "shard").mkdir(parents=True)
    (stale / "shard" / "part.npy").write_bytes(b"0" * 4096)
    res = run_cli("store", "gc", "--data-dir", str(data), env=env)
    assert res.returncode == 0 and "would remove 1 stale work" in res.stdout, res
    assert stale.exists()
    res = run_cli("store", "gc", "--data-dir", str(data), "--no-dry-run", "--json", env=env)
    assert res.returncode == 0 and res.json()["scratch_removed"] == [stale.name], res
    assert not stale.exists()


def test04_reupload_repairs_a_corrupt_object(server: Server, tmp_path: Path) -> None:
    png = _png(tmp_path / "b.png", 9)
    ref = run_cli("import", str(png), env=server.env()).stdout.strip()
    _damage(server.data_dir, ref)
    assert run_cli("fetch", ref, "-o", str(tmp_path / "x.png"), env=server.env()).returncode == 1
    again = run_cli("import", str(png), env=server.env())
    assert again.returncode == 0 and again.stdout.strip() == ref, again
    res = run_cli("fetch", ref, "-o", str(tmp_path / "y.png"), env=server.env())
    assert res.returncode == 0, res
    assert (tmp_path / "y.png").read_bytes() == png.read_bytes()


def test05_verify_reports_a_moved_object_and_repair_puts_it_back(tmp_path: Path) -> None:
    """Issue 21 item 7: an object moved out of ``store/objects`` used to pass ``store
    verify`` ("all intact", exit 0) and ``--repair`` did nothing."""
    env, data = base_env(), tmp_path / "d"
    png = _png(tmp_path / "originals" / "pic.png", 5)
    res = run_cli("import", str(png), "--data-dir", str(data), env=env)
    assert res.returncode == 0, res
    d = res.stdout.strip().removeprefix("sha256:")
    obj = data / "store" / "objects" / d[:2] / d[2:]
    obj.rename(tmp_path / "moved-away")
    res = run_cli("store", "verify", "--data-dir", str(data), env=env)
    assert res.returncode == 1, res
    assert "1 MISSING" in res.stdout and "all intact" not in res.stdout, res
    assert f"sha256:{d}" in res.stderr and "pic.png" in res.stderr, res
    res = run_cli("store", "verify", "--data-dir", str(data), "--json", env=env)
    assert res.returncode == 1 and [m["digest"] for m in res.json()["missing"]] == [d], res
    res = run_cli(
        "store", "verify", "--data-dir", str(data), "--repair",
        "--source", str(png.parent), env=env,
    )  # fmt: skip
    assert res.returncode == 0 and f"repaired sha256:{d}" in res.stdout, res
    assert obj.read_bytes() == png.read_bytes()
