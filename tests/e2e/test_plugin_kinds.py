"""Kinds from other packages, end to end: ``examples/plugin-kind`` installed beside matforge
(entry-point group ``matforge.kinds``), and two broken plugins beside it.

The example is installed with pip into a temporary ``--target`` folder, never into the
project's venv (it would leak into every other test), and the server and CLI subprocesses
get that folder on ``PYTHONPATH``, where ``importlib.metadata`` finds its entry point. The
broken plugins are a hand-written ``.dist-info`` (an import error; a kind named ``render``).

Checked: ``matforge kinds`` lists the plugin's kind and names the broken plugins; the server
starts, logs them, and lists them in ``GET /api/plugins``; the kind is in ``GET /api/kinds``,
``/openapi.json`` and the dashboard; its spec is validated (422 naming the field); it runs
through the REST API in a worker process, its two tables as shards in the pool's spawned
processes; its rows are in ``matforge results``; ``report.pareto`` and ``select`` read them;
the built-in kinds keep working (``generate.merl`` runs, ``render`` is the built-in one).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import matforge
from tests.e2e.harness import REPO, Server, base_env, run_cli, start_server, stop_server

EXAMPLE = REPO / "examples" / "plugin-kind"
KIND = "fit.ashikhmin_shirley"
#: Seconds a job of this test may take on a shared 2-core machine (measured: generate.merl
#: of two tables about 10 s, the fit about 10 s).
JOB_TIMEOUT_S = 240.0

BROKEN_IMPORT = "import matforge_this_module_does_not_exist  # noqa: F401\n"
BROKEN_RENDER = """
from jobapi.kinds import Kind, register
from jobapi.params import StrictModel


class P(StrictModel):
    pass


def run(params, ctx):
    raise AssertionError("the plugin's render must never run")


register(Kind(name="render", params=P, runner=run, description="a plugin's render"))
"""


def install_example(root: Path) -> Path:
    """pip-install ``examples/plugin-kind`` (a copy: the build leaves files beside the
    sources) into ``root/site``, offline and without dependencies; returns that folder."""
    src = root / "src"
    shutil.copytree(
        EXAMPLE, src, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__")
    )
    site = root / "site"
    cmd = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
           "--no-build-isolation", "--target", str(site), str(src)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return site


def write_broken_plugins(root: Path) -> Path:
    """A distribution ``matforge-broken-plugins`` with two broken entry points."""
    site = root / "broken"
    info = site / "matforge_broken_plugins-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: matforge-broken-plugins\nVersion: 0.1\n"
    )
    (info / "entry_points.txt").write_text(
        "[matforge.kinds]\n"
        "broken-import = matforge_broken_import\n"
        "broken-render = matforge_broken_render\n"
    )
    (site / "matforge_broken_import.py").write_text(BROKEN_IMPORT)
    (site / "matforge_broken_render.py").write_text(BROKEN_RENDER)
    return site


@pytest.fixture(scope="module")
def pythonpath(tmp_path_factory: pytest.TempPathFactory) -> str:
    root = tmp_path_factory.mktemp("plugins")
    paths = [str(install_example(root)), str(write_broken_plugins(root))]
    if os.environ.get("PYTHONPATH"):
        paths.append(os.environ["PYTHONPATH"])
    return os.pathsep.join(paths)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, pythonpath: str) -> Iterator[Server]:
    srv = start_server(
        tmp_path_factory.mktemp("plugin-server"),
        token="plugin-token",
        workers=1,
        extra_env={"PYTHONPATH": pythonpath, "MATFORGE_POOL_PROCESSES": "2"},
    )
    try:
        yield srv
    finally:
        assert stop_server(srv) == [], "processes outlived the server"


@pytest.fixture(scope="module")
def client(server: Server) -> Iterator[matforge.Client]:
    with matforge.Client(server.url, token=server.token) as mf:
        yield mf


def run_job(client: matforge.Client, spec: dict[str, Any]) -> dict[str, Any]:
    job = client.submit(spec)
    return client.wait(job, timeout=JOB_TIMEOUT_S)


def fetch_json(client: matforge.Client, job: dict[str, Any], name: str) -> Any:
    return json.loads(client.fetch(f"job:{job['id']}/{name}"))


@pytest.fixture(scope="module")
def fitted(client: matforge.Client) -> dict[str, dict[str, Any]]:
    """A generate.merl job of two tables, then the plugin's fit of them."""
    gen = run_job(
        client,
        {"kind": "generate.merl", "seed": 1,
         "params": {"collection": {"families": {"plastic": 1, "metal": 1}}}},
    )  # fmt: skip
    fit = run_job(
        client,
        {"kind": KIND, "seed": 0,
         "params": {"dataset": f"job:{gen['id']}", "fit_pairs": 4096, "eval_pairs": 16384,
                    "exponents": 12}},
    )  # fmt: skip
    return {"gen": gen, "fit": fit}


def test01_matforge_kinds_lists_the_plugin_and_the_broken_ones(pythonpath: str) -> None:
    env = base_env(PYTHONPATH=pythonpath)
    res = run_cli("kinds", "--json", env=env)
    assert res.returncode == 0, res
    docs = {d["name"]: d for d in res.json()}
    assert docs[KIND]["plugin"] == "matforge-ashikhmin"
    assert set(docs[KIND]["params_schema"]["properties"]) >= {"dataset", "fit_pairs"}
    assert docs["render"]["plugin"] is None
    assert docs["render"]["summary"] != "a plugin's render"
    assert "plugin 'broken-import'" in res.stderr and "ModuleNotFoundError" in res.stderr
    assert "matforge_this_module_does_not_exist" in res.stderr
    assert "plugin 'broken-render'" in res.stderr
    assert "kind 'render' collides with the built-in kind" in res.stderr

    res = run_cli("kinds", KIND, env=env)
    assert res.returncode == 0, res
    assert "fit_pairs" in res.stdout and "plugin: matforge-ashikhmin" in res.stdout
    # Without the folder on the path the kind is unknown: nothing leaked into the venv.
    res = run_cli("kinds", KIND, env=base_env())
    assert res.returncode == 2 and "unknown kind" in res.stderr, res


def test02_server_reports_broken_plugins_and_serves_the_kind(server: Server) -> None:
    log = server.log_path.read_text(errors="replace")
    assert "plugin broken-import" in log and "not loaded" in log
    assert "collides with the built-in kind" in log
    assert f"plugin ashikhmin (from matforge-ashikhmin): kinds {KIND}" in log
    with server.http() as http:
        plugins = {p["name"]: p for p in http.get("/api/plugins").json()}
        assert plugins["ashikhmin"]["kinds"] == [KIND] and plugins["ashikhmin"]["error"] is None
        assert plugins["ashikhmin"]["distribution"] == "matforge-ashikhmin"
        assert "ModuleNotFoundError" in plugins["broken-import"]["error"]
        assert plugins["broken-render"]["kinds"] == []
        assert "collides" in plugins["broken-render"]["error"]

        kinds = {k["name"]: k for k in http.get("/api/kinds").json()}
        assert kinds[KIND]["plugin"] == "matforge-ashikhmin"
        assert kinds["render"]["plugin"] is None

        doc = http.get("/openapi.json").json()
        schemas = doc["components"]["schemas"]
        assert f"params.{KIND}" in schemas and f"JobCreate.{KIND}" in schemas
        assert "/api/plugins" in doc["paths"]

        r = http.post("/api/jobs", json={"kind": KIND, "params": {"dataset": "job:" + "0" * 32,
                                                                   "fit_pairs": 10}})  # fmt: skip
        assert r.status_code == 422 and "fit_pairs" in r.text, r.text


def test03_runs_through_the_rest_api(client: matforge.Client, fitted: dict[str, Any]) -> None:
    fit = fitted["fit"]
    assert fit["state"] == "succeeded" and fit["kind"] == KIND
    names = {a["name"] for a in client.artifacts(fit)}
    assert names >= {"metrics.json", "model.json"}
    metrics = fetch_json(client, fit, "metrics.json")
    assert sorted(m["family"] for m in metrics["materials"]) == ["metal", "plastic"]
    for m in metrics["materials"]:
        # Floored SMAPE is in [0, 2]; a fit that failed sits near 1 or above. (Plain SMAPE
        # is near 2 for a near-mirror metal whatever the model: its table is exactly 0
        # at most pairs, where any smooth lobe is not.)
        assert 0 <= m["smape_floor"] < 0.5, m
        assert 1 <= m["n"] <= 1e4 and len(m["rs"]) == 3 and len(m["rd"]) == 3
        if m["family"] == "metal":
            assert max(m["rd"]) < 0.01, m  # a conductor has no diffuse term
    model = fetch_json(client, fit, "model.json")
    assert model["format"] == "matforge-ashikhmin.fit/1"
    manifest = client.manifest(fit)
    assert manifest["executor"] == "process"  # the shards went through the spawned pool


def test04_rows_results_pareto_and_select(
    server: Server, client: matforge.Client, fitted: dict[str, Any], pythonpath: str
) -> None:
    fit = fitted["fit"]
    res = run_cli("results", fit["id"], "--json", env=server.env(PYTHONPATH=pythonpath))
    assert res.returncode == 0, res
    rows = res.json()
    assert {r["candidate"] for r in rows} == {"ashikhmin-shirley"}
    assert {r["metric"] for r in rows} == {"brdf.smape", "brdf.smape_floor", "brdf.mae"}
    assert {r["kind"] for r in rows} == {KIND}
    mean = [r for r in rows if r["material"] == "mean" and r["metric"] == "brdf.smape"]
    assert len(mean) == 1 and mean[0]["bytes_per_material"] == 28
    assert mean[0]["dataset"] == f"job:{fitted['gen']['id']}"

    pareto = run_job(client, {"kind": "report.pareto", "params": {"runs": [f"job:{fit['id']}"]}})
    doc = fetch_json(client, pareto, "pareto.json")
    points = [pt for p in doc["panels"] if p["metric"] == "brdf.smape" for pt in p["points"]]
    assert [(pt["candidate"], pt["kind"], pt["front"]) for pt in points] == [
        ("ashikhmin-shirley", KIND, True)
    ]
    assert points[0]["mean"] == pytest.approx(mean[0]["value"])

    select = run_job(
        client,
        {"kind": "select", "params": {"runs": [f"job:{fit['id']}"], "metric": "smape_floor",
                                      "target": 0.5, "cost": "bytes_per_material"}},
    )  # fmt: skip
    ladders = fetch_json(client, select, "select.json")["ladders"]
    assert [lad["chosen"] for lad in ladders] == ["ashikhmin-shirley"]
    floor = next(r for r in rows if r["material"] == "mean" and r["metric"] == "brdf.smape_floor")
    assert ladders[0]["rungs"][0]["value"] == pytest.approx(floor["value"])
    assert ladders[0]["rungs"][0]["cost"] == 28


def test05_dashboard_shows_the_plugin_job(server: Server, fitted: dict[str, Any]) -> None:
    with server.http() as http:
        page = http.get(f"/jobs/{fitted['fit']['id']}")
        assert page.status_code == 200, page.text[:500]
        assert KIND in page.text and "Ashikhmin-Shirley fit" in page.text
        summary = http.get(f"/api/jobs/{fitted['fit']['id']}/summary").json()
        assert summary["title"] == "Ashikhmin-Shirley fit"
        assert set(summary["rows"]) == {m["name"] for m in _materials(http, fitted)} | {"mean"}
        index = http.get("/")
        assert index.status_code == 200 and KIND in index.text


def _materials(http: Any, fitted: dict[str, Any]) -> list[dict[str, Any]]:
    ref = next(a for a in fitted["fit"]["artifacts"] if a["name"] == "metrics.json")
    return list(json.loads(http.get(f"/api/artifacts/{ref['digest']}").content)["materials"])
