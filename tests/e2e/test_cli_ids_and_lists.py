"""Issue 14 §5, the CLI: short ids, ``ls``, ``kinds``, resubmission notices, ``fetch -o -``
and the umask, ``status`` of a score job, the final message in full, tables that fit,
and ``batch --parallel / --continue-on-error``.

Most tests use a server with no workers, beside which ``matforge run --data-dir`` makes
finished jobs in the same data directory: jobs submitted through the server then stay
queued, which makes short-id collisions and list filters deterministic.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from .conftest import _stop
from .harness import SMOKE_RENDER, Server, matforge_exe, run_cli, start_server

pytestmark = pytest.mark.slow


def spec_file(path: Path, spec: dict[str, Any]) -> Path:
    path.write_text(json.dumps(spec))
    return path


def render(seed: int, name: str | None = None, **mitsuba: Any) -> dict[str, Any]:
    spec: dict[str, Any] = json.loads(json.dumps(SMOKE_RENDER))
    spec["seed"] = seed
    if name is not None:
        spec["name"] = name
    if mitsuba:
        spec["params"]["material"] = {"mitsuba": mitsuba}
    return spec


@pytest.fixture(scope="module")
def idle(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """A server without workers: what it queues stays queued."""
    srv = start_server(tmp_path_factory.mktemp("idle"), workers=0)
    try:
        yield srv
    finally:
        _stop(srv)


@pytest.fixture(scope="module")
def done(idle: Server, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A render named ``first`` and a score of it, run in process into the idle server's
    data directory: ``{"render": doc, "score": doc}``."""
    d = tmp_path_factory.mktemp("done")
    env = idle.env()
    data = ["--data-dir", str(idle.data_dir)]
    res = run_cli("run", str(spec_file(d / "r.json", render(1, "first"))), "--json", *data, env=env)
    assert res.returncode == 0, res
    rendered = res.json()
    score = {
        "kind": "score",
        "params": {
            "reference": f"job:{rendered['id']}/image.exr",
            "candidates": {"self": f"job:{rendered['id'][:10]}/image.exr"},
            "metrics": ["psnr", "mae"],
        },
    }
    res = run_cli("run", str(spec_file(d / "s.json", score)), "--json", *data, env=env)
    assert res.returncode == 0, res
    scored = res.json()
    # the short ref was written out in full before the spec was hashed
    assert scored["spec"]["params"]["candidates"]["self"].startswith(f"job:{rendered['id']}/")
    return {"render": rendered, "score": scored}


def test01_short_ids_everywhere(idle: Server, done: dict[str, Any], tmp_path: Path) -> None:
    job_id = done["render"]["id"]
    env = idle.env()
    status = run_cli("status", job_id[:12], "--json", env=env)
    assert status.returncode == 0, status
    assert status.json()["id"] == job_id
    listed = run_cli("artifacts", job_id[:6], "--json", env=env)
    assert listed.returncode == 0 and "image.exr" in {a["name"] for a in listed.json()}
    local = run_cli("artifacts", job_id[:6], "--data-dir", str(idle.data_dir), env=env)
    assert local.returncode == 0 and "image.exr" in local.stdout, local
    out = tmp_path / "img.exr"
    fetched = run_cli("fetch", f"job:{job_id[:8]}/image.exr", "-o", str(out), env=env)
    assert fetched.returncode == 0, fetched
    art = next(a for a in done["render"]["artifacts"] if a["name"] == "image.exr")
    assert hashlib.sha256(out.read_bytes()).hexdigest() == art["digest"]
    waited = run_cli("wait", job_id[:9], env=env)
    assert waited.returncode == 0 and waited.stdout.strip() == f"{job_id} succeeded"
    with idle.http() as http:
        assert http.get(f"/api/jobs/{job_id[:7]}").json()["id"] == job_id
        assert http.get(f"/api/jobs/{job_id[:7]}/artifacts").status_code == 200
        assert http.get(f"/api/jobs/{'f' * 31}").status_code in (404, 422)


def queued_ids(idle: Server, n: int, start: int) -> list[str]:
    """Submit ``n`` renders (seeds from ``start``) that stay queued; their ids."""
    ids = []
    with idle.http() as http:
        for seed in range(start, start + n):
            r = http.post("/api/jobs", json=render(seed, f"batch-job {seed}"))
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
    return ids


def test02_ambiguous_prefix_is_a_clear_error(idle: Server, tmp_path: Path) -> None:
    ids = queued_ids(idle, 17, start=100)  # 17 ids over 16 first digits: two share one
    by_digit: dict[str, list[str]] = {}
    for i in ids:
        by_digit.setdefault(i[0], []).append(i)
    digit, same = next((d, v) for d, v in by_digit.items() if len(v) > 1)
    res = run_cli("status", digit, env=idle.env())
    assert res.returncode == 2, res
    assert "ambiguous" in res.stderr and same[0][:12] in res.stderr, res
    assert "Traceback" not in res.stderr
    with idle.http() as http:
        r = http.get(f"/api/jobs/{digit}")
        assert r.status_code == 422 and "ambiguous" in r.json()["error"]
    missing = run_cli("status", "0123456789abcdef0123456789abcdef", env=idle.env())
    assert missing.returncode == 2 and "no job" in missing.stderr


def test03_ls(idle: Server, done: dict[str, Any]) -> None:
    env = idle.env()
    named = run_cli("ls", "--name", "FIRST", "--json", env=env)
    assert named.returncode == 0, named
    assert [d["id"] for d in named.json()] == [done["render"]["id"]]
    table = run_cli("ls", "--kind", "render", "--state", "succeeded", env=env)
    assert table.returncode == 0 and done["render"]["id"][:12] in table.stdout, table
    assert done["render"]["id"] not in table.stdout  # ids are shortened
    limited = run_cli("ls", "--state", "queued", "--limit", "3", "--json", env=env)
    assert limited.returncode == 0, limited
    docs = limited.json()
    assert len(docs) == 3 and {d["state"] for d in docs} == {"queued"}
    more = run_cli("ls", "--state", "queued", "--limit", "3", env=env)
    assert "showing 3 of" in more.stderr, more
    bad = run_cli("ls", "--kind", "scor", env=env)
    assert bad.returncode == 2 and "kind" in bad.stderr and "score" in bad.stderr, bad
    bad_state = run_cli("ls", "--state", "done", env=env)
    assert bad_state.returncode == 2 and "state" in bad_state.stderr, bad_state
    narrow = run_cli("ls", env={**env, "COLUMNS": "70"})
    assert narrow.returncode == 0, narrow
    assert max(len(line) for line in narrow.stdout.splitlines()) <= 70, narrow.stdout


def test04_kinds(idle: Server) -> None:
    env = idle.env()
    res = run_cli("kinds", env=env)
    assert res.returncode == 0 and "render" in res.stdout and "score" in res.stdout, res
    one = run_cli("kinds", "render", env=env)
    assert one.returncode == 0, one
    assert "spp" in one.stdout and "image.exr" in one.stdout and "resolution" in one.stdout
    doc = run_cli("kinds", "score", "--json", env=env).json()
    assert doc["name"] == "score" and "candidates" in doc["params_schema"]["properties"]
    bad = run_cli("kinds", "rendr", env=env)
    assert bad.returncode == 2 and "did you mean 'render'" in bad.stderr, bad


def test05_resubmission_says_so(idle: Server, done: dict[str, Any], tmp_path: Path) -> None:
    job_id = done["render"]["id"]
    same = spec_file(tmp_path / "same.json", render(1, "first"))
    res = run_cli("submit", str(same), env=idle.env())
    assert res.returncode == 0 and res.stdout.strip() == job_id, res
    assert f"reusing job {job_id} (same spec); add `force: true` to run again" in res.stderr
    assert "ignored" not in res.stderr
    renamed = spec_file(tmp_path / "renamed.json", render(1, "second"))
    res = run_cli("submit", str(renamed), "--json", env=idle.env())
    assert res.returncode == 0 and res.json()["id"] == job_id, res
    assert "reusing job" in res.stderr
    assert "'second' is ignored" in res.stderr and "'first'" in res.stderr, res
    fresh = spec_file(tmp_path / "fresh.json", render(77, "new"))
    res = run_cli("submit", str(fresh), env=idle.env())
    assert res.returncode == 0 and "reusing" not in res.stderr, res


def test06_fetch_to_stdout_and_umask(idle: Server, done: dict[str, Any], tmp_path: Path) -> None:
    art = next(a for a in done["render"]["artifacts"] if a["name"] == "preview.png")
    ref = f"job:{done['render']['id'][:12]}/preview.png"
    for extra in ([], ["--data-dir", str(idle.data_dir)]):
        proc = subprocess.run(
            [matforge_exe(), "fetch", ref, "-o", "-", *extra],
            env=idle.env(),
            capture_output=True,
            timeout=120,
        )
        assert proc.returncode == 0, proc.stderr
        assert hashlib.sha256(proc.stdout).hexdigest() == art["digest"]
        out = tmp_path / f"p{len(extra)}.png"
        proc = subprocess.run(
            [matforge_exe(), "fetch", ref, "-o", str(out), *extra],
            env=idle.env(),
            capture_output=True,
            timeout=120,
            preexec_fn=lambda: os.umask(0o027),  # noqa: PLW1509
        )
        assert proc.returncode == 0, proc.stderr
        assert out.stat().st_mode & 0o777 == 0o640


def test06b_fetch_a_whole_job_or_a_glob(idle: Server, done: dict[str, Any], tmp_path: Path) -> None:
    """``fetch job:ID -o dir/`` fetches every artifact, ``'job:ID/*.png'`` the matching ones;
    each file's bytes hash to its recorded digest (the reference: the job's artifact list)."""
    render = done["render"]
    digests = {a["name"]: a["digest"] for a in render["artifacts"]}
    for extra in ([], ["--data-dir", str(idle.data_dir)]):
        tag = "local" if extra else "server"
        whole = tmp_path / f"{tag}-all/"
        res = run_cli("fetch", f"job:{render['id'][:8]}", "-o", f"{whole}/", *extra, env=idle.env())
        assert res.returncode == 0, res
        got = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in whole.iterdir()}
        assert got == digests
        assert sorted(res.stdout.split()) == sorted(str(whole / n) for n in digests)
        pngs = tmp_path / f"{tag}-png"
        pngs.mkdir()
        res = run_cli("fetch", f"job:{render['id']}/*.png", "-o", str(pngs), "--json", *extra,
                      env=idle.env())  # fmt: skip
        assert res.returncode == 0, res
        assert {w["name"] for w in res.json()} == {n for n in digests if n.endswith(".png")}
        # no match: exit 2 naming the pattern and what the job has; a file as -o: exit 2
        res = run_cli("fetch", f"job:{render['id']}/*.txt", "-o", str(pngs), *extra,
                      env=idle.env())  # fmt: skip
        assert res.returncode == 2 and "*.txt" in res.stderr and "image.exr" in res.stderr, res
        res = run_cli("fetch", f"job:{render['id']}", "-o", str(tmp_path / "x.exr"), *extra,
                      env=idle.env())  # fmt: skip
        assert res.returncode == 2 and "directory" in res.stderr, res


def test07_status_of_a_score_job_shows_its_metrics(idle: Server, done: dict[str, Any]) -> None:
    res = run_cli("status", done["score"]["id"][:10], env=idle.env())
    assert res.returncode == 0, res
    assert "self" in res.stdout and "psnr" in res.stdout.lower() and "mae" in res.stdout.lower()


def test08_final_message_is_never_cut(idle: Server, tmp_path: Path) -> None:
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    (job_id,) = queued_ids(idle, 1, start=500)
    jobs = JobStore(idle.data_dir / "jobs.sqlite3")
    claimed = jobs.claim("test:1", 30.0, job_id=job_id)
    assert claimed is not None and claimed.lease_token
    manifest = ArtifactStore(idle.data_dir / "store").put_bytes(b"{}\n")
    long = "done: " + " ".join(f"step{i}=ok" for i in range(30)) + " THE-END"
    assert jobs.complete(job_id, claimed.lease_token, [], manifest.digest, message=long)
    res = run_cli("wait", job_id[:12], env=idle.env())
    assert res.returncode == 0, res
    assert "THE-END" in res.stderr and "step29=ok" in res.stderr, res.stderr
    status = run_cli("status", job_id[:12], env={**idle.env(), "COLUMNS": "60"})
    assert "THE-END" in status.stdout.replace("\n", " ").replace("  ", " "), status


def test09_batch_parallel_and_continue_on_error(server: Server, tmp_path: Path) -> None:
    steps = {
        "steps": [
            {"name": "a", "spec": render(41)},
            {
                "name": "bad",
                "spec": render(
                    42, type="twosided", bsdf={"type": "diffuse"}, extra={"type": "checkerboard"}
                ),
            },
            {
                "name": "needs_bad",
                "spec": {
                    "kind": "score",
                    "params": {
                        "reference": "step:a/image.exr",
                        "candidates": {"x": "step:bad/image.exr"},
                    },
                },
            },
            {"name": "b", "spec": render(43)},
        ]
    }
    f = tmp_path / "b.json"
    f.write_text(json.dumps(steps))
    res = run_cli(
        "batch", str(f), "--json", "--parallel", "2", "--continue-on-error", env=server.env()
    )
    assert res.returncode == 1, f"{res}\n{server.log_tail()}"
    rows = res.json()
    assert [r["state"] for r in rows] == ["succeeded", "failed", "skipped", "succeeded"], rows
    assert "needs step 'bad'" in rows[2]["error"]
    stop = run_cli("batch", str(f), "--json", env=server.env())
    assert stop.returncode == 1, stop
    assert [r["state"] for r in stop.json()] == ["succeeded", "failed", "skipped", "skipped"]


def test10_mitsuba_names_are_checked_before_queueing(idle: Server, tmp_path: Path) -> None:
    """Issue 14 §6: a plugin typo or an unknown named conductor exits 2 and queues nothing;
    a render without a material says which default it used."""
    with idle.http() as http:
        before = http.get("/api/jobs", params={"limit": 1}).headers["x-total-count"]
    for material, needle in (
        ({"type": "roughconductr"}, "did you mean 'roughconductor'"),
        ({"type": "roughconductor", "material": "Gold"}, "did you mean 'Au'"),
    ):
        spec = spec_file(
            tmp_path / "typo.json", {**render(900), "params": {"material": {"mitsuba": material}}}
        )
        res = run_cli("submit", str(spec), env=idle.env())
        assert res.returncode == 2, res
        assert "params.material" in res.stderr and needle in res.stderr, res
    with idle.http() as http:
        assert http.get("/api/jobs", params={"limit": 1}).headers["x-total-count"] == before
    plain = {"kind": "render", "params": {"resolution": [16, 16], "spp": 2}}
    data = ["--data-dir", str(tmp_path / "d")]
    res = run_cli(
        "run", str(spec_file(tmp_path / "plain.json", plain)), "--json", *data, env=idle.env()
    )
    assert res.returncode == 0, res
    assert "default grey diffuse (reflectance 0.5)" in res.json()["message"]
