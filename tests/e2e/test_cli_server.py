"""The service as a whole: ``matforge serve`` driven through the CLI and REST.

One server (1 worker) serves the whole module; tests that depend on an earlier job share it
through the ``rendered`` fixture. Exit codes are the contract's: 0 ok, 1 a job failed,
2 bad input or usage, 3 server unreachable or refused.
"""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from .harness import (
    SMOKE_RENDER,
    Server,
    base_env,
    closed_port_url,
    run_cli,
)

pytestmark = pytest.mark.slow


def write_spec(path: Path, spec: Any) -> Path:
    path.write_text(json.dumps(spec))
    return path


def render_spec(seed: int = 0, **material: Any) -> dict[str, Any]:
    spec = json.loads(json.dumps(SMOKE_RENDER))
    spec["seed"] = seed
    if material:
        spec["params"]["material"] = {"mitsuba": material}
    return spec


#: A material our checks pass and Mitsuba refuses in the job: twosided takes nested plugins
#: under any key, but reads only its BSDFs, so a texture there is an "unreferenced property".
IN_JOB_FAILURE = {
    "type": "twosided",
    "bsdf": {"type": "diffuse"},
    "extra": {"type": "checkerboard"},
}


def job_count(server: Server) -> int:
    with server.http() as http:
        jobs = http.get("/api/jobs").json()
    return len(jobs["jobs"] if isinstance(jobs, dict) else jobs)


@pytest.fixture(scope="module")
def rendered(server: Server, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The smoke render, submitted and waited for through the CLI: its final document."""
    spec = write_spec(tmp_path_factory.mktemp("specs") / "smoke.json", SMOKE_RENDER)
    sub = run_cli("submit", str(spec), env=server.env())
    assert sub.returncode == 0, sub
    job_id = sub.stdout.strip()
    assert len(job_id) == 32 and set(job_id) <= set("0123456789abcdef"), sub
    wait = run_cli("wait", job_id, env=server.env())
    assert wait.returncode == 0, f"{wait}\n--- server log ---\n{server.log_tail()}"
    assert wait.stdout.strip() == f"{job_id} succeeded"
    status = run_cli("status", job_id, "--json", env=server.env())
    assert status.returncode == 0, status
    doc: dict[str, Any] = status.json()
    return doc


# -- the happy path ---------------------------------------------------------------------------
def test01_health(server: Server) -> None:
    with server.http() as http:
        assert http.get("/api/health").json() == {"status": "ok"}


def test02_submit_wait_status(rendered: dict[str, Any], server: Server) -> None:
    doc = rendered
    assert doc["state"] == "succeeded" and doc["kind"] == "render"
    assert doc["attempts"] == 1 and doc["progress"] == 1.0 and doc["error"] is None
    assert {"image.exr", "preview.png"} <= {a["name"] for a in doc["artifacts"]}
    with server.http() as http:
        assert http.get(f"/api/jobs/{doc['id']}").json().keys() == doc.keys()
    human = run_cli("status", doc["id"], env=server.env())
    assert human.returncode == 0 and "succeeded" in human.stdout and "image.exr" in human.stdout


def test03_artifacts_match_rest(rendered: dict[str, Any], server: Server) -> None:
    listed = run_cli("artifacts", rendered["id"], "--json", env=server.env())
    assert listed.returncode == 0, listed
    with server.http() as http:
        rest = http.get(f"/api/jobs/{rendered['id']}/artifacts").json()
    assert listed.json() == rest
    local = run_cli(
        "artifacts", rendered["id"], "--json", "--data-dir", str(server.data_dir), env=base_env()
    )
    assert local.returncode == 0, local
    assert local.json() == rest
    table = run_cli("artifacts", rendered["id"], env=server.env())
    assert table.returncode == 0 and "image.exr" in table.stdout


def test04_fetch_equals_rest_download(
    rendered: dict[str, Any], server: Server, tmp_path: Path
) -> None:
    art = next(a for a in rendered["artifacts"] if a["name"] == "image.exr")
    with server.http() as http:
        rest_bytes = http.get(f"/api/artifacts/{art['digest']}").content
    assert hashlib.sha256(rest_bytes).hexdigest() == art["digest"]

    out = tmp_path / "image.exr"
    got = run_cli("fetch", f"job:{rendered['id']}/image.exr", "-o", str(out), env=server.env())
    assert got.returncode == 0, got
    assert got.stdout.strip() == str(out)
    assert out.read_bytes() == rest_bytes

    # by digest, into a directory, as JSON
    (tmp_path / "d").mkdir()
    by_sha = run_cli(
        "fetch", f"sha256:{art['digest']}", "-o", str(tmp_path / "d"), "--json", env=server.env()
    )
    assert by_sha.returncode == 0, by_sha
    info = by_sha.json()
    assert info["digest"] == art["digest"] and info["size"] == len(rest_bytes)
    assert Path(info["path"]).read_bytes() == rest_bytes

    # from the local store, no server involved
    local = tmp_path / "local.exr"
    loc = run_cli(
        "fetch",
        f"job:{rendered['id']}/image.exr",
        "-o",
        str(local),
        "--data-dir",
        str(server.data_dir),
        env=base_env(MATFORGE_SERVER=closed_port_url()),
    )
    assert loc.returncode == 0, loc
    assert local.read_bytes() == rest_bytes


def test05_resubmit_returns_the_same_job(
    rendered: dict[str, Any], server: Server, tmp_path: Path
) -> None:
    spec = write_spec(tmp_path / "smoke.yaml", SMOKE_RENDER)
    again = run_cli("submit", str(spec), "--wait", "--json", env=server.env())
    assert again.returncode == 0, again
    doc = again.json()  # exactly one JSON document on stdout
    assert doc["id"] == rendered["id"] and doc["state"] == "succeeded"


def test06_import_and_score(rendered: dict[str, Any], server: Server, tmp_path: Path) -> None:
    from storage.formats.exr import read_exr, write_exr

    fetched = tmp_path / "ref.exr"
    assert (
        run_cli(
            "fetch", f"job:{rendered['id']}/image.exr", "-o", str(fetched), env=server.env()
        ).returncode
        == 0
    )
    noisy = read_exr(fetched) * np.float32(1.25)
    upload = tmp_path / "brighter.exr"
    write_exr(upload, noisy)

    imp = run_cli("import", str(upload), "--json", env=server.env())
    assert imp.returncode == 0, imp
    info = imp.json()
    digest = hashlib.sha256(upload.read_bytes()).hexdigest()
    assert info["digest"] == digest and info["ref"] == f"sha256:{digest}"
    plain = run_cli("import", str(upload), env=server.env())
    assert plain.returncode == 0 and plain.stdout.strip() == f"sha256:{digest}"

    score = {
        "kind": "score",
        "params": {
            "reference": f"job:{rendered['id']}/image.exr",
            "candidates": {"bright": f"sha256:{digest}"},
        },
    }
    res = run_cli(
        "submit",
        str(write_spec(tmp_path / "score.json", score)),
        "--wait",
        "--json",
        env=server.env(),
    )
    assert res.returncode == 0, f"{res}\n{server.log_tail()}"
    doc = res.json()
    metrics_art = next(a for a in doc["artifacts"] if a["name"] == "metrics.json")
    out = tmp_path / "metrics.json"
    assert (
        run_cli(
            "fetch", f"sha256:{metrics_art['digest']}", "-o", str(out), env=server.env()
        ).returncode
        == 0
    )
    metrics = json.loads(out.read_text())
    assert "bright" in metrics["metrics"] and metrics["metrics"]["bright"]


def test07_import_rejects_a_malformed_file(server: Server, tmp_path: Path) -> None:
    bad = tmp_path / "broken.exr"
    bad.write_bytes(b"this is not an EXR file")
    res = run_cli("import", str(bad), env=server.env())
    assert res.returncode == 2, res
    assert "broken.exr" in res.stderr and "Traceback" not in res.stderr
    local = run_cli("import", str(bad), "--data-dir", str(tmp_path / "d"), env=base_env())
    assert local.returncode == 2 and "broken.exr" in local.stderr
    missing = run_cli("import", str(tmp_path / "nope.exr"), env=server.env())
    assert missing.returncode == 2 and "no such file" in missing.stderr


def test08_batch_with_step_refs(server: Server, tmp_path: Path) -> None:
    batch = {
        "steps": [
            {"name": "gold", "spec": render_spec(seed=1)},
            {"name": "rough", "spec": render_spec(seed=1, type="roughconductor", alpha=0.3)},
            {
                "name": "score",
                "spec": {
                    "kind": "score",
                    "params": {
                        "reference": "step:gold/image.exr",
                        "candidates": {
                            "rough": "step:rough/image.exr",
                            "same": "step:gold/image.exr",
                        },
                    },
                },
            },
        ]
    }
    f = tmp_path / "batch.yaml"
    f.write_text(json.dumps(batch))
    res = run_cli("batch", str(f), "--out", str(tmp_path / "results.csv"), env=server.env())
    assert res.returncode == 0, f"{res}\n{server.log_tail()}"
    # one line per step, with the step's headline result; no whole tables without -v
    assert "gold" in res.stdout and "score" in res.stdout
    assert len(res.stdout.splitlines()) < 20, res.stdout
    # --out: tidy result rows, one per measured value, as `matforge results FILE` writes
    with open(tmp_path / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["step"] for r in rows[:2]] == ["gold", "rough"]
    assert {r["metric"] for r in rows if r["step"] == "score"} >= {"image.flip"}
    assert {r["candidate"] for r in rows if r["step"] == "score"} == {"rough", "same"}
    assert len(rows[0]) < 30  # a fixed set of columns, not one per step and metric
    same = run_cli("results", str(f), "--out", str(tmp_path / "same.csv"), env=server.env())
    assert (
        same.returncode == 0
        and (tmp_path / "same.csv").read_text() == (tmp_path / "results.csv").read_text()
    )

    # the same batch again (jobs are reused) with -v, --json and --out .json
    res = run_cli(
        "batch", str(f), "-v", "--json", "--out", str(tmp_path / "results.json"), env=server.env()
    )
    assert res.returncode == 0, res
    printed = res.json()  # the steps, one each
    assert [r["step"] for r in printed] == ["gold", "rough", "score"]
    assert all(r["state"] == "succeeded" for r in printed)
    assert len(json.loads((tmp_path / "results.json").read_text())) == len(rows)
    assert "score: " in res.stderr  # -v: the score step's whole table (on stderr with --json)
    flip_cols = [c for c in printed[2] if c.endswith(".flip")]
    if flip_cols:  # identical images score a zero FLIP error
        assert printed[2]["same.flip"] == pytest.approx(0.0, abs=1e-6)


# -- exit codes -------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "spec, needle",
    [
        ({"kind": "render", "params": {**SMOKE_RENDER["params"], "colour": 1}}, "params.colour"),
        ({"kind": "render", "params": {**SMOKE_RENDER["params"], "spp": "many"}}, "params.spp"),
        ({"kind": "no_such_kind", "params": {}}, "kind"),
        ({**SMOKE_RENDER, "priority": 3}, "priority"),
        (
            {
                "kind": "score",
                "params": {
                    "reference": f"job:{'a' * 32}/image.exr",
                    "candidates": {"x": f"job:{'a' * 32}/image.exr"},
                },
            },
            "params.reference",
        ),
        (
            {"kind": "score", "params": {"reference": "not-a-ref", "candidates": {}}},
            "params.reference",
        ),
    ],
)
def test10_bad_spec_exits_2_and_queues_nothing(
    server: Server, tmp_path: Path, spec: dict[str, Any], needle: str
) -> None:
    before = job_count(server)
    path = write_spec(tmp_path / "bad.json", spec)
    for args in (("submit", str(path)), ("submit", str(path), "--wait", "--json")):
        res = run_cli(*args, env=server.env())
        assert res.returncode == 2, res
        assert needle in res.stderr, res
        assert res.stdout == "" and "Traceback" not in res.stderr
    assert job_count(server) == before


def test11_bad_files_and_usage_exit_2(server: Server, tmp_path: Path) -> None:
    res = run_cli("submit", str(tmp_path / "missing.json"), env=server.env())
    assert res.returncode == 2 and "no such file" in res.stderr, res
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("kind: [unclosed\n")
    res = run_cli("submit", str(garbage), env=server.env())
    assert res.returncode == 2 and "garbage.yaml" in res.stderr, res
    for args in (
        ("submit",),
        ("fetch", "job:x/y"),
        ("no-such-command",),
        ("status", "not-a-job-id"),
        ("fetch", "nonsense", "-o", str(tmp_path / "x")),
        ("status", "0" * 32),
    ):  # a well-formed id no job has: 404
        res = run_cli(*args, env=server.env())
        assert res.returncode == 2, res
        assert "Traceback" not in res.stderr


def test12_bad_batch_exits_2_before_submitting(server: Server, tmp_path: Path) -> None:
    before = job_count(server)
    f = tmp_path / "fwd.yaml"
    f.write_text(
        json.dumps(
            {
                "steps": [
                    {
                        "name": "score",
                        "spec": {
                            "kind": "score",
                            "params": {
                                "reference": "step:gold/image.exr",
                                "candidates": {"a": "step:gold/image.exr"},
                            },
                        },
                    },
                    {"name": "gold", "spec": render_spec(seed=11)},
                ]
            }
        )
    )
    res = run_cli("batch", str(f), env=server.env())
    assert res.returncode == 2, res
    assert "fwd.yaml" in res.stderr and "'score'" in res.stderr and "later step" in res.stderr
    f.write_text(
        json.dumps(
            {
                "steps": [
                    {"name": "a", "spec": render_spec(seed=12)},
                    {"name": "a", "spec": {"kind": "nope"}},
                ]
            }
        )
    )
    res = run_cli("batch", str(f), env=server.env())
    assert res.returncode == 2 and "duplicate step name 'a'" in res.stderr, res
    res = run_cli("batch", str(f), "--out", str(tmp_path / "r.txt"), env=server.env())
    assert res.returncode == 2, res
    assert job_count(server) == before


def test13_failed_job_exits_1(server: Server, tmp_path: Path) -> None:
    spec = write_spec(tmp_path / "fail.json", render_spec(**IN_JOB_FAILURE))
    res = run_cli("submit", str(spec), "--wait", "--json", env=server.env())
    assert res.returncode == 1, f"{res}\n{server.log_tail()}"
    doc = res.json()
    assert doc["state"] == "failed" and doc["error"]
    assert "\n" not in doc["error"] and "Traceback" not in res.stderr
    assert doc["error"] in res.stderr
    assert run_cli("wait", doc["id"], env=server.env()).returncode == 1
    status = run_cli("status", doc["id"], env=server.env())
    assert status.returncode == 0 and "failed" in status.stdout

    # in a batch: the failing step stops it, later steps are skipped, exit 1
    f = tmp_path / "b.yaml"
    f.write_text(
        json.dumps(
            {
                "steps": [
                    {"name": "bad", "spec": render_spec(**IN_JOB_FAILURE)},
                    {"name": "later", "spec": render_spec(seed=21)},
                ]
            }
        )
    )
    res = run_cli("batch", str(f), "--json", env=server.env())
    assert res.returncode == 1, res
    rows = res.json()
    assert [r["state"] for r in rows] == ["failed", "skipped"] and rows[0]["error"]


def test14_cancel(server: Server, tmp_path: Path) -> None:
    slow = render_spec(seed=31)
    slow["params"].update(resolution=[256, 256], spp=1024)  # ~10 s: the next job waits
    first = run_cli("submit", str(write_spec(tmp_path / "slow.json", slow)), env=server.env())
    queued = render_spec(seed=32)
    second = run_cli("submit", str(write_spec(tmp_path / "q.json", queued)), env=server.env())
    assert first.returncode == 0 and second.returncode == 0, (first, second)
    for job_id in (second.stdout.strip(), first.stdout.strip()):
        res = run_cli("cancel", job_id, "--json", env=server.env())
        assert res.returncode == 0, res
        assert res.json()["state"] in ("cancelled", "succeeded")
    res = run_cli("wait", second.stdout.strip(), env=server.env())
    assert res.returncode == 1 and "cancelled" in res.stdout, res


def test15_unreachable_server_exits_3(tmp_path: Path) -> None:
    spec = write_spec(tmp_path / "s.json", SMOKE_RENDER)
    env = base_env(MATFORGE_SERVER=closed_port_url())
    for args in (
        ("submit", str(spec)),
        ("status", "0" * 32),
        ("wait", "0" * 32),
        ("artifacts", "0" * 32, "--json"),
        ("import", str(spec)),
    ):
        res = run_cli(*args, env=env)
        assert res.returncode == 3, res
        assert "cannot reach" in res.stderr and res.stdout == ""
    res = run_cli("--server", closed_port_url(), "status", "0" * 32, env=base_env())
    assert res.returncode == 3, res


def test16_token(token_server: Server, tmp_path: Path) -> None:
    spec = write_spec(tmp_path / "s.json", SMOKE_RENDER)
    wrong = token_server.env(MATFORGE_TOKEN="wrong")
    res = run_cli("submit", str(spec), env=wrong)
    assert res.returncode == 3, res
    assert "401" in res.stderr and "MATFORGE_TOKEN" in res.stderr
    none = base_env(MATFORGE_SERVER=token_server.url)
    assert run_cli("status", "0" * 32, env=none).returncode == 3
    ok = run_cli("submit", str(spec), "--json", env=token_server.env())
    assert ok.returncode == 0, ok
    assert ok.json()["state"] == "queued"  # no workers on this server
    assert run_cli("cancel", ok.json()["id"], env=token_server.env()).returncode == 0


# -- in process: determinism and the job document ---------------------------------------------
def test20_run_is_deterministic(rendered: dict[str, Any], server: Server, tmp_path: Path) -> None:
    spec = write_spec(tmp_path / "smoke.json", SMOKE_RENDER)
    env = base_env()
    first = run_cli("run", str(spec), "--data-dir", str(tmp_path / "a"), "--json", env=env)
    assert first.returncode == 0, first
    doc = first.json()
    assert doc["state"] == "succeeded"
    assert doc.keys() == rendered.keys()  # the shape of GET /api/jobs/{id}
    again = run_cli("run", str(spec), "--data-dir", str(tmp_path / "a"), "--json", env=env)
    assert again.returncode == 0 and again.json()["id"] == doc["id"]
    assert again.json()["artifacts"] == doc["artifacts"]

    fresh = run_cli("run", str(spec), "--data-dir", str(tmp_path / "b"), env=env)
    assert fresh.returncode == 0, fresh
    fresh_id = fresh.stdout.strip()
    fresh_arts = run_cli(
        "artifacts", fresh_id, "--json", "--data-dir", str(tmp_path / "b"), env=env
    ).json()
    digests = {a["name"]: a["digest"] for a in doc["artifacts"]}
    assert {a["name"]: a["digest"] for a in fresh_arts} == digests
    # ... and the same bytes as the server's worker made
    assert {a["name"]: a["digest"] for a in rendered["artifacts"]} == digests

    out = tmp_path / "img.exr"
    assert (
        run_cli(
            "fetch",
            f"job:{fresh_id}/image.exr",
            "-o",
            str(out),
            "--data-dir",
            str(tmp_path / "b"),
            env=env,
        ).returncode
        == 0
    )
    assert hashlib.sha256(out.read_bytes()).hexdigest() == digests["image.exr"]


def test21_run_failures(tmp_path: Path) -> None:
    env = base_env()
    bad = write_spec(tmp_path / "bad.json", {"kind": "render", "params": {"nope": 1}})
    res = run_cli("run", str(bad), "--data-dir", str(tmp_path / "d"), env=env)
    assert res.returncode == 2 and "params.nope" in res.stderr, res
    failing = write_spec(tmp_path / "fail.json", render_spec(**IN_JOB_FAILURE))
    res = run_cli("run", str(failing), "--data-dir", str(tmp_path / "d"), "--json", env=env)
    assert res.returncode == 1, res
    assert res.json()["state"] == "failed" and "Traceback" not in res.stderr


def test22_store_verify_and_gc(tmp_path: Path) -> None:
    env = base_env()
    data = tmp_path / "d"
    spec = write_spec(tmp_path / "s.json", SMOKE_RENDER)
    job = run_cli("run", str(spec), "--data-dir", str(data), "--json", env=env).json()
    res = run_cli("store", "verify", "--data-dir", str(data), "--json", env=env)
    assert res.returncode == 0, res
    assert res.json()["ok"] is True and res.json()["checked"] >= 3
    res = run_cli("store", "gc", "--data-dir", str(data), "--grace-hours", "0", env=env)
    assert res.returncode == 0 and "would remove 0 objects" in res.stdout, res

    digest = next(a["digest"] for a in job["artifacts"] if a["name"] == "preview.png")
    obj = data / "store" / "objects" / digest[:2] / digest[2:]
    obj.chmod(0o644)
    obj.write_bytes(obj.read_bytes() + b"x")
    res = run_cli("store", "verify", "--data-dir", str(data), env=env)
    assert res.returncode == 1, res
    assert digest in res.stderr and "preview.png" in res.stderr
    res = run_cli(
        "fetch",
        f"job:{job['id']}/preview.png",
        "-o",
        str(tmp_path / "p.png"),
        "--data-dir",
        str(data),
        env=env,
    )
    assert res.returncode == 1 and "corrupt" in res.stderr, res
    assert not (tmp_path / "p.png").exists()
    res = run_cli("store", "verify", "--data-dir", str(tmp_path / "nothing-here"), env=env)
    assert res.returncode == 2, res
