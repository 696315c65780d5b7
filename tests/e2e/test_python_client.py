"""``matforge.Client`` against a real ``matforge serve``, ``matforge.datasets`` over REST
with its local cache, and the one version everywhere.

Oracles: the REST documents read with plain httpx; the same dataset read from the server's
data directory directly (``data_dir=``); the digests of the cached files; the installed
package metadata for the version.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import matforge
from matforge import datasets
from storage.formats.exr import exr_bytes

from .harness import Server, base_env, closed_port_url, matforge_exe, start_server, stop_server

GLINT = {"kind": "generate.glint", "seed": 3,
         "params": {"example": {"procedural": "isotropic_noise", "size": 8},
                    "ndf_resolution": 16}}  # fmt: skip


@pytest.fixture(scope="module")
def srv(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """A server (1 worker) whose data directory already holds a glint dataset, run in
    process with ``matforge.run`` before the server started."""
    root = tmp_path_factory.mktemp("pyclient")
    doc = matforge.run(GLINT, root / "data")
    server = start_server(root)
    try:
        yield server, doc
    finally:
        stop_server(server)


def test01_submit_wait_fetch_results(srv: tuple[Server, dict[str, Any]], tmp_path: Path) -> None:
    server, _ = srv
    spec = {**GLINT, "seed": 11}
    path = tmp_path / "spec.json"
    path.write_text(json.dumps(spec))
    with matforge.Client(server.url) as mf:
        job = mf.submit(spec)
        assert job["state"] in ("queued", "running", "succeeded")
        done = mf.wait(job, poll=0.1)
        assert done["state"] == "succeeded" and done["id"] == job["id"]
        assert mf.submit(path)["id"] == job["id"]  # a file, the identical spec: same job
        assert mf.status(job["id"][:8])["id"] == job["id"]
        assert job["id"] in [j["id"] for j in mf.ls(kind="generate.glint")]
        arts = mf.artifacts(f"job:{job['id'][:8]}")
        with server.http() as http:
            assert arts == http.get(f"/api/jobs/{job['id']}/artifacts").json()
        data = mf.fetch(f"job:{job['id']}/ndf.npz")
        (rec,) = [a for a in arts if a["name"] == "ndf.npz"]
        assert hashlib.sha256(data).hexdigest() == rec["digest"]
        size = mf.fetch(f"sha256:{rec['digest']}", tmp_path / "out" / "ndf.npz")
        assert size == len(data) == (tmp_path / "out" / "ndf.npz").stat().st_size
        rows = mf.results(job["id"])
        assert rows and {r["job"] for r in rows} == {job["id"]}
        with server.http() as http:
            expect = http.get("/api/results", params={"job": job["id"]}).json()
        assert rows == expect
        assert mf.cancel(job["id"])["state"] == "succeeded"  # finished: unchanged
        # The worker's log of the run: its attempt, and the end the job document shows.
        log = mf.logs(job["id"][:8])
        assert f"attempt {done['attempts']}: generate.glint on worker " in log
        assert log.rstrip().endswith(f"attempt {done['attempts']}: succeeded")
        assert mf.logs(job, tail=1) == log.splitlines(keepends=True)[-1]
        with server.http() as http:
            assert http.get(f"/api/jobs/{job['id']}/logs").text == log


def test02_typed_errors(srv: tuple[Server, dict[str, Any]], tmp_path: Path) -> None:
    server, _ = srv
    with matforge.Client(server.url) as mf:
        bad = {**GLINT, "params": {**GLINT["params"], "ndf_resolution": -1}}
        with pytest.raises(matforge.SpecError) as err:
            mf.submit(bad)
        assert err.value.field == "params.ndf_resolution", err.value.errors
        assert "ndf_resolution" in str(err.value) and err.value.exit_code == 2
        with pytest.raises(matforge.SpecError, match="kind"):
            mf.submit({"kind": "no.such.kind"})
        # a normal map that is not one: accepted as an EXR, refused by the job
        exr = tmp_path / "zeros.exr"
        exr.write_bytes(exr_bytes(np.zeros((8, 8, 3), np.float32)))
        ref = mf.upload(exr)["ref"]
        job = mf.submit({"kind": "generate.glint", "params": {"example": {"normal_map": ref}}})
        with pytest.raises(matforge.JobFailed) as failed:
            mf.wait(job, poll=0.1)
        assert failed.value.job["state"] == "failed" and failed.value.job["error"]
        assert failed.value.exit_code == 1
        assert mf.wait(job, check=False)["state"] == "failed"
        with pytest.raises(matforge.BadInput, match="no artifact"):
            mf.fetch(f"job:{srv[1]['id']}/nothing.npz")
    with pytest.raises(matforge.ServerUnreachable) as unreachable:
        matforge.Client(closed_port_url()).status("abc")
    assert unreachable.value.exit_code == 3
    with pytest.raises(matforge.SpecError) as local:
        matforge.run(bad, tmp_path / "data")
    assert local.value.field == "params.ndf_resolution"


def test03_settings_from_the_environment(
    srv: tuple[Server, dict[str, Any]], monkeypatch: pytest.MonkeyPatch
) -> None:
    server, doc = srv
    monkeypatch.setenv("MATFORGE_SERVER", server.url)
    with matforge.Client() as mf:
        assert mf.server == server.url and mf.status(doc["id"])["state"] == "succeeded"


def test04_datasets_over_rest_cached_once(
    srv: tuple[Server, dict[str, Any]], tmp_path: Path
) -> None:
    server, doc = srv
    cache = tmp_path / "cache"
    local = datasets.open(doc["id"], data_dir=server.data_dir)
    with matforge.Client(server.url) as mf:
        fetched: list[str] = []
        real_fetch = mf.fetch

        def counting_fetch(ref: str, dest: Any = None, mode: int = 0o644) -> Any:
            fetched.append(ref)
            return real_fetch(ref, dest, mode)

        mf.fetch = counting_fetch  # type: ignore[method-assign]
        remote = datasets.open(doc["id"], client=mf, cache_dir=cache)
        assert isinstance(remote, datasets.GlintExample)
        for a, b in zip(remote.levels, local.levels, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(remote.example, local.example)
        first = sorted(fetched)
        assert first == sorted(a["digest"] for a in doc["artifacts"]
                               if a["name"] in ("example.exr", "ndf.npz", "lobes.npz",
                                                "stats.json"))  # fmt: skip
        for d in first:  # each cached file holds exactly its digest's bytes
            p = cache / "objects" / d[:2] / d[2:]
            assert hashlib.sha256(p.read_bytes()).hexdigest() == d
        fetched.clear()
        datasets.open(doc["id"], client=mf, cache_dir=cache)
        assert fetched == []  # downloaded once
        (ndf,) = [a["digest"] for a in doc["artifacts"] if a["name"] == "ndf.npz"]
        damaged = cache / "objects" / ndf[:2] / ndf[2:]
        damaged.chmod(0o644)
        damaged.write_bytes(b"\0" * damaged.stat().st_size)  # same size, wrong bytes
        again = datasets.open(doc["id"], client=mf, cache_dir=cache)
        assert fetched == [ndf]  # re-downloaded, not read
        np.testing.assert_array_equal(again.levels[0], local.levels[0])


def test05_one_version(srv: tuple[Server, dict[str, Any]]) -> None:
    server, doc = srv
    version = matforge.__version__
    assert version == metadata.version("matforge")
    done = subprocess.run([matforge_exe(), "--version"], capture_output=True, text=True,
                          timeout=60, env=base_env())  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip() == f"matforge {version}"
    with server.http() as http:
        assert http.get("/openapi.json").json()["info"]["version"] == version
        manifest = http.get(f"/api/jobs/{doc['id']}/manifest").json()
    assert manifest["matforge_version"] == version
    with matforge.Client(server.url) as mf:
        assert mf.manifest(doc["id"][:10]) == manifest


def test06_batch(srv: tuple[Server, dict[str, Any]], tmp_path: Path) -> None:
    server, _ = srv
    batch = tmp_path / "batch.json"
    batch.write_text(json.dumps({"steps": [{"name": "g", "spec": {**GLINT, "seed": 21}}]}))
    with matforge.Client(server.url) as mf:
        rows = mf.batch(batch)
        assert [(r["step"], r["state"]) for r in rows] == [("g", "succeeded")]
        by_batch = mf.results(str(batch))  # a batch's rows name their step
        assert {r["step"] for r in by_batch} == {"g"}
        by_job = mf.results(rows[0]["job_id"])
        assert [{**r, "step": None} for r in by_batch] == by_job


def test07_token_from_the_environment(
    token_server: Server, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MATFORGE_SERVER", token_server.url)
    monkeypatch.delenv("MATFORGE_TOKEN", raising=False)
    with matforge.Client() as mf, pytest.raises(matforge.ServerRefused, match="MATFORGE_TOKEN"):
        mf.ls()
    monkeypatch.setenv("MATFORGE_TOKEN", token_server.token or "")
    with matforge.Client() as mf:
        assert mf.ls() == []
