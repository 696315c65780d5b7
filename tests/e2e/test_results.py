"""The results table end to end: ``GET /api/results``, ``POST /api/results/batch`` and
``matforge results`` against ``matforge serve`` (and a local store with ``--data-dir``).

A batch renders a reference (8 spp) and two candidates (1 and 2 spp) and scores them; its
results come back in step order, each score row with its candidate render's spp and time.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest

from .harness import SMOKE_RENDER, Server, base_env, run_cli

pytestmark = pytest.mark.slow

COLUMNS = [
    "job",
    "step",
    "kind",
    "dataset",
    "scene",
    "candidate",
    "material",
    "family",
    "split",
    "config",
    "metric",
    "value",
    "lower_is_better",
    "seed",
    "ns_per_eval",
    "runtime",
    "ms_per_frame",
    "bytes_per_material",
    "bytes_per_network",
    "train_seconds",
    "spp",
    "render_seconds",
    "macs_per_eval",
    "bytes_per_eval",
]


def render(seed: int, spp: int) -> dict[str, Any]:
    spec = json.loads(json.dumps(SMOKE_RENDER))
    spec["seed"], spec["params"]["spp"] = seed, spp
    return spec


BATCH = {
    "steps": [
        {"name": "gt", "spec": render(1, 8)},
        {"name": "one", "spec": render(2, 1)},
        {"name": "two", "spec": render(2, 2)},
        {
            "name": "score",
            "spec": {
                "kind": "score",
                "params": {
                    "reference": "step:gt/image.exr",
                    "metrics": ["flip", "psnr"],
                    "candidates": {"spp2": "step:two/image.exr", "spp1": "step:one/image.exr"},
                },
            },
        },
    ]
}


@pytest.fixture(scope="module")
def batch(server: Server, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    """The batch file, run once through ``matforge batch``; its job ids in step order."""
    f = tmp_path_factory.mktemp("results") / "scores.yaml"
    f.write_text(json.dumps(BATCH))
    res = run_cli("batch", str(f), "--json", env=server.env())
    assert res.returncode == 0, f"{res}\n{server.log_tail()}"
    return f, [r["job_id"] for r in res.json()]


def test01_rest_json_and_csv(server: Server, batch: tuple[Path, list[str]]) -> None:
    _, ids = batch
    with server.http() as http:
        rows = http.get("/api/results", params={"job": ids[3]}).json()
        # a job alone: its candidates as stored (canonical, sorted); a batch keeps its order
        # image metrics say their space (an image MAE is not a BRDF-space one)
        assert [(r["candidate"], r["metric"]) for r in rows] == [
            ("spp1", "image.flip"),
            ("spp1", "image.psnr"),
            ("spp2", "image.flip"),
            ("spp2", "image.psnr"),
        ]
        flip = {r["candidate"]: r for r in rows if r["metric"] == "image.flip"}
        assert (flip["spp1"]["spp"], flip["spp2"]["spp"]) == (1, 2)
        assert flip["spp1"]["lower_is_better"] is True and flip["spp1"]["scene"] == "sphere_env"
        # render_seconds is the render's own time (its passes less JIT compilation), as its
        # manifest records it; the job's wall time (Mitsuba import, scene load) is more
        run_s = http.get(f"/api/jobs/{ids[1]}").json()["timings"]["run_seconds"]
        manifest = http.get(f"/api/jobs/{ids[1]}/manifest").json()
        own = manifest["timings"]["measured"]["render_seconds"]
        assert flip["spp1"]["render_seconds"] == pytest.approx(own)
        assert 0 < own < run_s
        assert list(rows[0]) == COLUMNS
        # filters; the render rows of the batch's jobs, in the order asked
        # the old name stands for its space's
        psnr = http.get("/api/results", params={"metric": "psnr", "kind": "score"}).json()
        assert {r["metric"] for r in psnr} == {"image.psnr"} and len(psnr) == 2
        # an unknown metric or kind is a 422 naming it and the closest, never an empty list
        for params, needle in (
            ({"metric": "psnr_avg"}, "did you mean 'image.psnr'"),
            ({"kind": "scor"}, "did you mean 'score'"),
        ):
            res = http.get("/api/results", params=params)
            assert res.status_code == 422 and needle in res.text, res.text
        renders = http.get("/api/results", params={"job": [ids[2], ids[0]]}).json()
        assert [(r["job"], r["metric"]) for r in renders] == [
            (ids[2], "render_seconds"),
            (ids[0], "render_seconds"),
        ]
        # CSV by format= and by Accept
        text = http.get("/api/results", params={"job": ids[3], "format": "csv"})
        assert text.headers["content-type"].startswith("text/csv")
        table = list(csv.DictReader(io.StringIO(text.text)))
        assert [r["metric"] for r in table] == ["image.flip", "image.psnr"] * 2
        assert float(table[0]["value"]) == pytest.approx(rows[0]["value"])
        assert json.loads(table[0]["config"])["spp"] == 1
        accept = http.get("/api/results", params={"job": ids[3]}, headers={"Accept": "text/csv"})
        assert accept.text == text.text
        # errors: a malformed id 422, an unknown one 404
        assert http.get("/api/results", params={"job": "nope"}).status_code == 422
        assert http.get("/api/results", params={"job": "0" * 32}).status_code == 404


def test02_rest_batch(server: Server, batch: tuple[Path, list[str]]) -> None:
    _, ids = batch
    with server.http() as http:
        doc = http.post("/api/results/batch", json={"steps": BATCH["steps"]}).json()
        assert [(s["step"], s["job"], s["state"]) for s in doc["steps"]] == [
            (s["name"], i, "succeeded") for s, i in zip(BATCH["steps"], ids, strict=True)
        ]
        assert [r["step"] for r in doc["rows"]] == ["gt", "one", "two"] + ["score"] * 4
        bad = {"steps": [{"name": "x", "spec": {"kind": "render", "params": {"spp": "many"}}}]}
        res = http.post("/api/results/batch", json=bad)
        assert res.status_code == 422 and "spp" in res.text


def test03_cli_results(server: Server, batch: tuple[Path, list[str]], tmp_path: Path) -> None:
    f, ids = batch
    out = tmp_path / "r.csv"
    res = run_cli("results", str(f), "--out", str(out), env=server.env())
    assert res.returncode == 0, res
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == COLUMNS
    assert [r["step"] for r in rows] == ["gt", "one", "two"] + ["score"] * 4  # batch order
    assert [r["candidate"] for r in rows[3:]] == ["spp2", "spp2", "spp1", "spp1"]  # as given
    assert [r["spp"] for r in rows[3:]] == ["2", "2", "1", "1"]
    printed = run_cli("results", ids[3], "--json", "--metric", "flip", env=server.env())
    assert printed.returncode == 0, printed
    assert [(r["candidate"], r["metric"]) for r in printed.json()] == [
        ("spp1", "image.flip"),
        ("spp2", "image.flip"),
    ]
    as_json = tmp_path / "r.json"
    assert run_cli("results", ids[3], "--out", str(as_json), env=server.env()).returncode == 0
    assert len(json.loads(as_json.read_text())) == 4
    human = run_cli("results", ids[3], env=server.env())
    assert human.returncode == 0 and "spp1" in human.stdout and "flip" in human.stdout
    # the same from the server's data directory, without the server
    local = run_cli("results", ids[3], "--json", "--data-dir", str(server.data_dir), env=base_env())
    assert local.returncode == 0, local
    remote = run_cli("results", ids[3], "--json", env=server.env())
    assert local.json() == remote.json()
    # a short id (a unique prefix, as `ls` prints them) names the same job, both ways
    short = ids[3][:8]
    for env, extra in ((server.env(), []), (base_env(), ["--data-dir", str(server.data_dir)])):
        by_prefix = run_cli("results", short, "--json", *extra, env=env)
        assert by_prefix.returncode == 0, by_prefix
        assert by_prefix.json() == remote.json()


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--out", "x.txt"], "must end in .csv or .json"),
        (["not-a-job"], "neither a job id"),
        (["0" * 31 + "g"], "neither a job id"),
        (["--metric", "smape_mean"], "did you mean 'brdf.smape'"),
        (["--kind", "trian.brdf"], "did you mean 'train.brdf'"),
        (["--pivot", "--by", "candidat"], "did you mean 'candidate'"),
    ],
)
def test04_cli_bad_input_exits_2(server: Server, args: list[str], needle: str) -> None:
    res = run_cli("results", *args, env=server.env())
    assert res.returncode == 2 and needle in res.stderr, res


def test05_cli_pivot(server: Server, batch: tuple[Path, list[str]], tmp_path: Path) -> None:
    """``results --pivot``: a row per candidate, the means of the tidy rows (the reference:
    the same rows through ``--json``), the best per column marked."""
    f, ids = batch
    tidy = run_cli("results", ids[3], "--json", env=server.env()).json()
    res = run_cli("results", ids[3], "--pivot", "--json", env=server.env())
    assert res.returncode == 0, res
    doc = res.json()
    assert doc["format"] == "matforge.pivot/1" and sorted(doc["methods"]) == ["spp1", "spp2"]
    for meth in doc["methods"]:
        flips = [r["value"] for r in tidy if r["candidate"] == meth and r["metric"] == "image.flip"]
        assert doc["cells"][meth]["image.flip"]["mean"] == pytest.approx(sum(flips) / len(flips))
    lowest = min(doc["methods"], key=lambda m: doc["cells"][m]["image.flip"]["mean"])
    assert doc["best"]["image.flip"] == lowest
    out = tmp_path / "pivot.csv"
    human = run_cli("results", str(f), "--pivot", "--out", str(out), env=server.env())
    assert human.returncode == 0 and "*" in human.stdout + human.stderr, human
    with open(out, newline="") as fh:
        assert {r["method"] for r in csv.DictReader(fh)} >= {"spp1", "spp2", "gt"}
    bad = run_cli("results", ids[3], "--pivot", "--by", "colour", env=server.env())
    assert bad.returncode == 2 and "--by colour" in bad.stderr


def test07_a_recipes_results_without_repeating_its_vars(server: Server, tmp_path: Path) -> None:
    """A batch file with a variable (``vars: {scene: null}``), run with ``--var``: its
    results are read without the ``--var``, from its last run's jobs (they failed with
    "vars.scene: no value"), and are the results read with it."""
    recipe = {
        "vars": {"scene": None},
        "steps": [{"name": "img", "spec": {**render(7, 2), "name": "recipe render"}}],
    }
    recipe["steps"][0]["spec"]["params"]["scene"] = "var:scene"
    f = tmp_path / "recipe.yaml"
    f.write_text(json.dumps(recipe))
    ran = run_cli("batch", str(f), "--var", "scene=sphere_env", env=server.env())
    assert ran.returncode == 0, f"{ran}\n{server.log_tail()}"
    given = run_cli("results", str(f), "--json", "--var", "scene=sphere_env", env=server.env())
    assert given.returncode == 0, given
    read = run_cli("results", str(f), "--json", env=server.env())
    assert read.returncode == 0, read
    assert read.json() == given.json() and [r["step"] for r in read.json()] == ["img"] * len(
        read.json()
    )
    assert "--var scene=sphere_env (its run 'recipe.yaml " in read.stderr
    pivot = run_cli("results", str(f), "--pivot", env={**server.env(), "COLUMNS": "100"})
    assert pivot.returncode == 0 and "img" in pivot.stdout, pivot
