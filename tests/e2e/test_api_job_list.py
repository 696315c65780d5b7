"""``GET /api/jobs`` as the job list needs it (issue 14 §3): search by name, unknown filter
values refused with a 422 naming the filter, sort orders, paging past 200 jobs with
``X-Total-Count``, and short (prefix) job ids on ``/api/jobs/{id}``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.settings import Settings
from storage.jobs import JobStore


def render(seed: int, name: str | None = None) -> dict[str, Any]:
    spec: dict[str, Any] = {
        "kind": "render",
        "seed": seed,
        "params": {"scene": "sphere_env", "material": {"mitsuba": {"type": "diffuse"}}},
    }
    if name is not None:
        spec["name"] = name
    return spec


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings)) as c:
        yield c


def test01_name_search_ignores_case_and_matches_part(client: TestClient) -> None:
    for seed, name in enumerate(["Gold sphere", "aluminium", "gold_plane", None]):
        assert client.post("/api/jobs", json=render(seed, name)).status_code == 201
    got = client.get("/api/jobs", params={"name": "GOLD"})
    assert got.status_code == 200
    assert [j["name"] for j in got.json()] == ["gold_plane", "Gold sphere"]
    assert got.headers["x-total-count"] == "2"
    # LIKE wildcards are literal
    assert client.get("/api/jobs", params={"name": "%"}).json() == []
    assert [j["name"] for j in client.get("/api/jobs", params={"name": "_"}).json()] == [
        "gold_plane"
    ]


@pytest.mark.parametrize(
    "query, needle",
    [
        ({"kind": "scor"}, "query.kind"),
        ({"state": "done"}, "query.state"),
        ({"sort": "size"}, "query.sort"),
    ],
)
def test02_unknown_filter_values_are_a_422_naming_the_filter(
    client: TestClient, query: dict[str, str], needle: str
) -> None:
    r = client.get("/api/jobs", params=query)
    assert r.status_code == 422, r.text
    assert needle.split(".")[1] in r.json()["error"]
    assert any(needle.split(".") == [str(p) for p in d["loc"]] for d in r.json()["detail"])
    if "kind" in query:
        assert "did you mean 'score'" in r.json()["error"]


def test03_paging_past_200_jobs_and_sorting(client: TestClient, tmp_path: Path) -> None:
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    for i in range(230):  # straight into the queue: 230 submissions through REST are slow
        jobs.submit(
            kind="render" if i % 2 else "score",
            name=f"job {i:03d}",
            seed=i,
            spec_hash=f"{i:064x}",
            spec={"kind": "render"},
        )
    first = client.get("/api/jobs")
    assert len(first.json()) == 200 and first.headers["x-total-count"] == "230"
    rest = client.get("/api/jobs", params={"offset": 200})
    assert len(rest.json()) == 30
    names = [j["name"] for j in first.json() + rest.json()]
    assert names == [f"job {i:03d}" for i in reversed(range(230))]
    oldest = client.get("/api/jobs", params={"sort": "created", "limit": 2}).json()
    assert [j["name"] for j in oldest] == ["job 000", "job 001"]
    by_name = client.get("/api/jobs", params={"sort": "-name", "limit": 1}).json()
    assert by_name[0]["name"] == "job 229"
    by_kind = client.get("/api/jobs", params={"sort": "kind", "limit": 1}).json()
    assert by_kind[0]["kind"] == "render"
    scores = client.get("/api/jobs", params={"kind": "score", "limit": 5})
    assert scores.headers["x-total-count"] == "115"


def test04_short_ids(client: TestClient) -> None:
    doc = client.post("/api/jobs", json=render(1)).json()
    short = doc["id"][:8]
    assert client.get(f"/api/jobs/{short}").json()["id"] == doc["id"]
    assert client.post(f"/api/jobs/{short}/cancel").json()["state"] == "cancelled"
    assert client.get(f"/api/jobs/{short}/artifacts").json() == []
    assert client.get("/api/jobs/XYZ").status_code == 422  # not hex at all
    unknown = "0" * 32 if not doc["id"].startswith("0") else "1" * 32
    assert client.get(f"/api/jobs/{unknown}").status_code == 404


def test05_batch_label(client: TestClient) -> None:
    """A spec's ``batch`` label groups jobs; like ``name`` it is not part of the identity.
    A reused job (same spec) also joins the batch that asked for it."""
    a = client.post("/api/jobs", json={**render(1), "batch": "run one"}).json()
    b = client.post("/api/jobs", json={**render(2), "batch": "run one"}).json()
    client.post("/api/jobs", json=render(3))
    again = client.post("/api/jobs", json={**render(1), "batch": "run two"})
    assert again.status_code == 200 and again.json()["id"] == a["id"]
    assert again.json()["batch"] == "run one"  # the job keeps its first batch
    got = client.get("/api/jobs", params={"batch": "run one"})
    assert [j["id"] for j in got.json()] == [b["id"], a["id"]]
    assert got.headers["x-total-count"] == "2"
    # ... and joins the batch that asked for it again, so that batch's group shows it
    two = client.get("/api/jobs", params={"batch": "run two"})
    assert [j["id"] for j in two.json()] == [a["id"]] and two.headers["x-total-count"] == "1"
    client.post("/api/jobs", json={**render(1), "batch": "run two"})  # asked twice: once
    assert len(client.get("/api/jobs", params={"batch": "run two"}).json()) == 1
    assert a["batch"] == "run one" and a["spec"]["batch"] == "run one"


def test06_short_refs_in_specs_are_written_out(client: TestClient, tmp_path: Path) -> None:
    """``job:<prefix>/<name>`` and ``job:<prefix>`` in params get the full id before the spec
    is hashed; an unknown prefix is a 422 naming the field."""
    from service.submission import expand_short_refs

    made = client.post("/api/jobs", json=render(5)).json()
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    raw = {
        "kind": "x",
        "params": {"a": f"job:{made['id'][:6]}/image.exr", "b": [f"job:{made['id'][:7]}"]},
    }
    out = expand_short_refs(raw, jobs)
    assert out["params"] == {"a": f"job:{made['id']}/image.exr", "b": [f"job:{made['id']}"]}
    assert raw["params"]["a"].startswith("job:") and len(raw["params"]["a"]) < 30  # not modified
    unknown = "0" if not made["id"].startswith("0") else "1"
    bad = {
        **render(6),
        "params": {**render(6)["params"], "material": {"merl": f"job:{unknown * 5}/x.binary"}},
    }
    r = client.post("/api/jobs", json=bad)
    assert r.status_code == 422 and "params.material.merl" in r.json()["error"], r.text
    assert "no job" in r.json()["error"]


def test07_live_documents_of_a_running_job(client: TestClient, tmp_path: Path) -> None:
    """A running job publishes its curves so far; GET /api/jobs/{id}/live/{name} serves the
    latest (``null`` before the first), and publications are rate-limited."""
    from jobapi.context import JobContext
    from storage.artifacts import ArtifactStore

    doc = client.post("/api/jobs", json=render(9)).json()
    jobs, store = JobStore(tmp_path / "jobs.sqlite3"), ArtifactStore(tmp_path / "store")
    assert jobs.claim("t:1", 30.0, job_id=doc["id"]) is not None
    ctx = JobContext(
        job_id=doc["id"], seed=9, spec=doc["spec"], store=store, jobs=jobs, workdir=tmp_path
    )
    live = f"/api/jobs/{doc['id'][:8]}/live/curves.json"
    assert client.get(live).json() is None
    assert ctx.publish("curves.json", {"step": [1], "loss": [2.0]})
    assert not ctx.publish("curves.json", {"step": [1, 2], "loss": [2.0, 1.0]})  # too soon
    assert client.get(live).json() == {"step": [1], "loss": [2.0]}
    assert ctx.publish("curves.json", {"step": [1, 2], "loss": [2.0, 1.0]}, min_interval_s=0)
    assert client.get(live).json()["step"] == [1, 2]
    assert not ctx.publish("curves.json", {"loss": [float("nan")]}, min_interval_s=0)
    assert client.get(f"/api/jobs/{doc['id']}/live/other.json").json() is None
    assert ctx.artifacts == {}  # live documents are not artifacts
