"""``GET /api/jobs?columns=&filter=&tag=`` and ``PATCH /api/jobs/{id}`` (rename, tags), and
``matforge ls --column --filter`` refusing a bad filter with exit 2 before any request."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.api import create_app
from service.cli.main import main
from service.settings import Settings


def render(seed: int, typ: str, **extra: Any) -> dict[str, Any]:
    material = {"mitsuba": {"type": typ, **extra}}
    return {"kind": "render", "seed": seed, "params": {"scene": "sphere_env", "material": material}}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    settings = Settings.from_env({}).with_(data_dir=tmp_path)
    with TestClient(create_app(settings)) as c:
        yield c


def test01_param_columns_and_filters(client: TestClient) -> None:
    a = client.post("/api/jobs", json=render(1, "diffuse")).json()
    b = client.post("/api/jobs", json=render(2, "roughconductor", alpha=0.2)).json()
    c = client.post("/api/jobs", json=render(3, "roughconductor", alpha=0.4)).json()
    key = "params.material.mitsuba.type"
    got = client.get("/api/jobs", params={"columns": f"{key},params.material.mitsuba.alpha"})
    assert got.status_code == 200
    cols = {j["id"]: j["columns"] for j in got.json()}
    assert cols[a["id"]] == {key: "diffuse", "params.material.mitsuba.alpha": None}
    assert cols[b["id"]]["params.material.mitsuba.alpha"] == pytest.approx(0.2)
    rough = client.get("/api/jobs", params={"filter": f"{key}=roughconductor"})
    assert [j["id"] for j in rough.json()] == [c["id"], b["id"]]
    assert rough.headers["x-total-count"] == "2"
    low = client.get(
        "/api/jobs",
        params={"filter": [f"{key}=roughconductor", "params.material.mitsuba.alpha<0.3"]},
    )
    assert [j["id"] for j in low.json()] == [b["id"]]
    # a queued job has no metrics: a metric filter keeps none of them
    assert client.get("/api/jobs", params={"filter": "metric.psnr>0"}).json() == []
    for bad, needle in (("params.x~1", "query.filter"), ("metric.psnr<high", "needs a number")):
        res = client.get("/api/jobs", params={"filter": bad})
        assert res.status_code == 422 and needle in res.text, res.text
    res = client.get("/api/jobs", params={"columns": "spec.kind"})
    assert res.status_code == 422 and "query.columns" in res.text


def test02_rename_and_tags(client: TestClient) -> None:
    job = client.post("/api/jobs", json=render(1, "diffuse")).json()
    res = client.patch(f"/api/jobs/{job['id'][:8]}", json={"name": "gold", "add_tags": ["ref"]})
    assert res.status_code == 200, res.text
    doc = res.json()
    assert doc["name"] == "gold" and doc["tags"] == ["ref"]
    assert doc["spec_hash"] == job["spec_hash"]  # a label, not an input
    assert [j["id"] for j in client.get("/api/jobs", params={"name": "gold"}).json()] == [job["id"]]
    assert [j["id"] for j in client.get("/api/jobs", params={"tag": "ref"}).json()] == [job["id"]]
    doc = client.patch(f"/api/jobs/{job['id']}", json={"remove_tags": ["ref"]}).json()
    assert doc["tags"] == [] and doc["name"] == "gold"
    assert client.get("/api/jobs", params={"tag": "ref"}).json() == []
    bad = client.patch(f"/api/jobs/{job['id']}", json={"add_tags": ["two words"]})
    assert bad.status_code == 422 and "add_tags.0" in bad.text
    assert client.patch(f"/api/jobs/{'f' * 32}", json={"name": "x"}).status_code == 404


def test03_ls_refuses_a_bad_filter_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """Refused before any request: the server address is one nothing listens on."""
    with pytest.raises(SystemExit) as exit_info:
        main(["--server", "http://127.0.0.1:9", "ls", "-f", "params.x~1"])
    assert exit_info.value.code == 2
    assert "--filter" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("query", "needle"),
    [
        # the docs' old example: a metric no kind writes was an empty column, not an error
        ({"columns": "metric.smape_mean"}, "did you mean 'metric.brdf.smape'"),
        ({"filter": "metric.smape_mean<0.1"}, "did you mean 'metric.brdf.smape'"),
        ({"columns": "params.modle"}, "did you mean 'params.model'"),
        # one column, one unit: the old name of two spaces' MAE is refused
        ({"columns": "metric.mae"}, "'metric.brdf.mae' or 'metric.image.mae'"),
    ],
)
def test04_unknown_metrics_and_params_are_refused(
    client: TestClient, query: dict[str, str], needle: str
) -> None:
    res = client.get("/api/jobs", params=query)
    assert res.status_code == 422 and needle in res.text, res.text
    where = "query.columns" if "columns" in query else "query.filter"
    assert where in res.text


def test05_known_and_old_metric_names_are_columns(client: TestClient) -> None:
    for query in ({"columns": "metric.brdf.smape,metric.image.psnr,metric.smape"},
                  {"filter": "metric.brdf.smape<0.1"}):  # fmt: skip
        assert client.get("/api/jobs", params=query).status_code == 200, query


def test06_ls_refuses_an_unknown_metric_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    """``matforge ls --filter 'metric.smape_mean<0.1'`` printed "no jobs match"; it is now
    refused before any request (nothing listens on the server address)."""
    with pytest.raises(SystemExit) as exit_info:
        main(["--server", "http://127.0.0.1:9", "ls", "-f", "metric.smape_mean<0.1"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--filter" in err and "did you mean 'metric.brdf.smape'" in err, err
