"""The job page's tables for training and report jobs (server-rendered HTML and the JSON the
page's chart script reads), through the real app with a TestClient.

A test-only kind writes what ``train.brdf``, ``train.fabric``, ``report.brdf`` and ``score``
write (a per-material ``metrics.json`` with ``curves.png``; a ``pareto.json`` with claims and
``pareto.png``; a whole-model score), and its summary hook is the real hook of that kind:
the page shows whatever the hook returns and knows no kind's fields.
References: the documents themselves: every material, the mean row and every claim appear,
the chart data carries the numbers unchanged, and the PNGs are in the gallery.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Iterator
from typing import Any, Literal

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import Field

from evaluators.report.select import summarize as select_summary
from evaluators.score.kind import summarize as score_summary
from generators.merl.kind import summarize as merl_summary
from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from jobapi.results import ArtifactReader, ResultTable
from models.brdf.kind import summarize as brdf_summary
from models.brdf.report_kind import summarize as report_summary
from models.fabric.kind import summarize as fabric_summary
from service import kinds
from service.api import create_app
from service.settings import Settings
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.formats.png import write_png
from storage.jobs import JobStore
from tests.helpers.job_documents import brdf_metrics, brdf_scores, fabric_metrics, merl_materials

TRAIN_METRICS = brdf_metrics(
    [brdf_scores("gold", "metal", "train", smape=0.11, smape_floor=0.1, mae=0.02,
                 smape_analytic=0.3, mae_analytic=0.05),
     brdf_scores("film", "iridescent", "heldout", smape=0.4, smape_floor=0.35, mae=0.1,
                 smape_analytic=0.6, mae_analytic=0.2)],
    smape=0.255, smape_floor=0.225, mae=0.06, smape_analytic=0.45, mae_analytic=0.125,
)  # fmt: skip
PARETO = {
    # report.brdf's document: its configurations (points, what its summary reads) and the
    # panels of the one pareto.json schema (docs/artifacts.md)
    "format": "matforge.brdf-report/1",
    "runs": [],
    "panels": [{"metric": "smape", "cost": "ns_per_eval", "front": ["analytic", "hybrid 16x3"],
                "points": [{"candidate": "analytic", "mean": 0.2, "cost": 2.0, "front": True},
                           {"candidate": "hybrid 16x3", "mean": 0.1, "cost": 60.0,
                            "front": True}]}],
    "points": [
        {"config": "analytic", "n": 3, "smape_mean": 0.2, "ns_per_eval": 2.0, "pareto": True},
        {"config": "hybrid 16x3", "n": 3, "smape_mean": 0.1, "ns_per_eval": 60.0,
         "pareto": True},
    ],
    "claims": [
        {"claim": "hybrid 16x3 mean SMAPE < analytic", "holds": True},
        {"claim": "hybrid 32x3 mean SMAPE <= neural 32x3 at equal per-material parameters",
         "holds": None, "why": "no neural 32x3 run in the report"},
    ],
}  # fmt: skip


def _fabric_row(name: str, rel: float) -> dict[str, Any]:
    comps = {c: {"mse": rel / 10, "rel": rel} for c in ("C_warp", "C_weft", "S_warp", "S_weft")}
    return {"name": name, "pattern": "plain", "queries": 128, "loss": rel / 2,
            **comps, "rgb": {"mse": rel / 10, "rel": rel},
            "baseline": {"loss": 0.4, **comps, "rgb": {"mse": 0.1, "rel": 1.1}}}  # fmt: skip


#: ``train.fabric``'s nested per-component metrics.json.
FABRIC_METRICS = fabric_metrics(
    [_fabric_row("plain-0", 0.2), _fabric_row("twill-0", 0.4)],
    {"count": 2, "loss": 0.15, "rgb": {"mse": 0.03, "rel": 0.3},
     "baseline": {"loss": 0.4, "rgb": {"mse": 0.1, "rel": 1.1}}},
)  # fmt: skip

SAMPLING = "bin centre in (sqrt theta_h, theta_d, phi_d), phi_h = 0"
#: ``generate.merl``'s materials: a collection's table quality (measured, not scored).
MERL_MATERIALS = merl_materials(
    [{"name": f"iridescent-00{i}-Au", "family": "iridescent", "source": {"mitsuba": {}},
      "tabulation": {"max_rel_error": 0.001 * (i + 1), "bins": 90, "sampling": SAMPLING}}
     for i in range(3)]
)  # fmt: skip


def _rung(candidate: str, value: float, cost: float, meets: bool) -> dict[str, Any]:
    return {"candidate": candidate, "value": value, "n": 1, "min": value, "max": value,
            "cost": cost, "runtime": "drjit-fused", "meets": meets}  # fmt: skip


#: ``select``'s ladder: the cheapest rung fails the target, the next one is chosen.
SELECT = {
    "format": "matforge.select/1", "metric": "smape", "target": 0.1, "cost": "ns_per_eval",
    "lower_is_better": True,
    "ladders": [{"dataset": None, "scene": None, "metric": "smape", "cost": "ns_per_eval",
                 "cost_label": None, "chosen": "hybrid 16x3", "why": "cheapest meeting it",
                 "rungs": [_rung("analytic", 0.4, 2.0, False),
                           _rung("hybrid 16x3", 0.08, 30.0, True),
                           _rung("hybrid 32x3", 0.05, 60.0, True)]}],
}  # fmt: skip

#: ``score`` of whole models against a set of tables (means, then rows per material).
SET_SCORE = {
    "reference": "job:" + "0" * 32,
    "metrics": {"hybrid": {"smape": 0.2, "mae": 0.03}},
    "per_material": {"hybrid": {"gold": {"smape": 0.1, "mae": 0.02},
                                "film": {"smape": 0.3, "mae": 0.04}}},
    "settings": {},
}  # fmt: skip


class TablesParams(StrictModel):
    """Params of the test-only kind."""

    what: Literal["train", "report", "set", "fabric", "merl", "select"] = Field(
        description="which job's artifacts to write"
    )


def run_tables(params: TablesParams, ctx: JobContext) -> None:
    png = write_png(None, np.zeros((4, 4, 3), dtype=np.uint8))
    if params.what == "select":
        ctx.put_json("select.json", SELECT)
    elif params.what == "merl":
        ctx.put_json("materials.json", MERL_MATERIALS)
    elif params.what == "set":
        ctx.put_json("metrics.json", SET_SCORE)
    elif params.what == "fabric":
        ctx.put_json("metrics.json", FABRIC_METRICS)
    elif params.what == "train":
        ctx.put_json("metrics.json", TRAIN_METRICS)
        ctx.put_bytes("curves.png", png, "image/png")
    else:
        ctx.put_json("pareto.json", PARETO)
        ctx.put_bytes("pareto.png", png, "image/png")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The summary hook of the kind whose artifacts the job wrote."""
    if read("pareto.json") is not None:
        return report_summary(read)
    if read("materials.json") is not None:
        return merl_summary(read)
    if read("select.json") is not None:
        return select_summary(read)
    doc = read("metrics.json")
    if isinstance(doc, dict) and "metrics" in doc:
        return score_summary(read)
    if isinstance(doc, dict) and any("smape" in m for m in doc["materials"]):
        return brdf_summary(read)
    return fabric_summary(read)


@pytest.fixture
def client(settings: Settings, monkeypatch: pytest.MonkeyPatch) -> Iterator[TestClient]:
    kinds.load_builtin()
    kind = Kind("test_tables", TablesParams, run_tables, "test-only tables kind", summary=summarize)
    monkeypatch.setitem(jobapi_kinds._KINDS, kind.name, kind)
    with TestClient(create_app(settings)) as c:
        yield c


def page(client: TestClient, settings: Settings, what: str) -> tuple[str, Any]:
    """The job page's HTML and its ``metrics-data`` JSON, for a finished job."""
    jobs = JobStore(settings.db_path)
    try:
        job, _ = submit({"kind": "test_tables", "params": {"what": what}}, jobs,
                        ArtifactStore(settings.store_dir))  # fmt: skip
    finally:
        jobs.close()
    assert run_worker(settings, max_jobs=1) == 1
    r = client.get(f"/jobs/{job.id}")
    assert r.status_code == 200, r.text
    m = re.search(r'<script type="application/json" id="metrics-data">(.*?)</script>', r.text, re.S)
    assert m is not None
    return r.text, json.loads(html.unescape(m.group(1)))


def test01_training_metrics_per_material(client: TestClient, settings: Settings) -> None:
    text, data = page(client, settings, "train")
    assert "Metrics per material" in text and "<th>Material</th>" in text
    assert data["labels"] == ["gold", "film", "mean"]
    assert data["names"] == ["family", "split", "smape", "smape_floor", "mae", "smape_analytic",
                             "mae_analytic"]  # fmt: skip
    assert data["rows"]["film"]["smape"] == 0.4 and data["rows"]["mean"]["mae"] == 0.06
    assert data["rows"]["gold"]["family"] == "metal"
    assert len(re.findall(r"<tr><td>(gold|film|mean)</td>", text)) == 3
    assert 'alt="curves.png"' in text


def test02_report_pareto_and_claims(client: TestClient, settings: Settings) -> None:
    text, data = page(client, settings, "report")
    assert "Accuracy against cost" in text and "<th>Configuration</th>" in text
    assert data["labels"] == ["analytic", "hybrid 16x3"]
    assert data["rows"]["hybrid 16x3"]["ns_per_eval"] == 60.0
    assert 'id="claims-table"' in text
    assert "hybrid 16x3 mean SMAPE &lt; analytic" in text and "no neural 32x3 run" in text
    assert 'alt="pareto.png"' in text


def test03_whole_model_scores_per_material(client: TestClient, settings: Settings) -> None:
    text, data = page(client, settings, "set")
    assert data["labels"] == ["hybrid", "hybrid / film", "hybrid / gold"]  # JSON keys sorted
    assert data["rows"]["hybrid / film"] == {"smape": 0.3, "mae": 0.04}
    assert "<th>Candidate</th>" in text and "Reference" in text


def test04_fabric_training_metrics_flattened(client: TestClient, settings: Settings) -> None:
    """train.fabric's nested metrics become dotted columns; the mean row keeps what it has."""
    text, data = page(client, settings, "fabric")
    assert data["labels"] == ["plain-0", "twill-0", "mean"]
    assert data["names"][:6] == ["pattern", "queries", "loss", "baseline.loss", "rgb.rel",
                                 "baseline.rgb.rel"]  # fmt: skip
    assert data["rows"]["twill-0"]["rgb.rel"] == 0.4
    assert data["rows"]["twill-0"]["S_weft.rel"] == 0.4
    assert data["rows"]["mean"]["baseline.rgb.rel"] == 1.1
    assert data["rows"]["mean"]["C_warp.rel"] is None
    assert "Metrics per material" in text


def test05_method_table_cells_in_si_units() -> None:
    """The method x metric table shows costs and metrics with SI prefixes and units (issue:
    "use SI prefixes and units everywhere"), and keeps the raw value for readers; the
    expected strings are worked by hand."""
    from service.routes.dashboard import _pivot_cell

    def cell(name: str, role: str, **got: float) -> dict[str, object]:
        return _pivot_cell({"name": name, "role": role}, dict(got))

    assert cell("torch_ns", "cost", median=82700.0) == {"text": "82.7 \u00b5s", "value": 82700.0}
    assert cell("ns_per_eval", "cost", median=13.13)["text"] == "13.13 ns"
    assert cell("bytes_per_material", "cost", median=1528000.0)["text"] == "1.528 MB"
    assert cell("train_seconds", "cost", median=0.85)["text"] == "850 ms"
    assert cell("smape", "metric", mean=0.7238, std=0.01)["text"] == "0.7238 \u00b1 0.01"
    assert cell("psnr", "metric", mean=31.2, std=0.5)["text"] == "31.2 dB \u00b1 0.5 dB"
    assert _pivot_cell({"name": "smape", "role": "metric"}, None) == {"text": "", "value": None}


def test06_a_datasets_items_have_no_best(client: TestClient, settings: Settings) -> None:
    """A MERL collection's table quality is measured, not ranked: no column names a best
    material (the charts said "best: iridescent-000-Au"), and no cell is marked; a
    model's per-material scores still have their best."""
    text, data = page(client, settings, "merl")
    assert data["labels"] == ["iridescent-000-Au", "iridescent-001-Au", "iridescent-002-Au"]
    assert data["better"]["tabulation.max_rel_error"] == "lower"  # an error, by its name
    assert data["best"] == {} and data["ranked"] is False
    assert 'class="num mono best"' not in text
    _, train = page(client, settings, "train")
    assert train["best"]["smape"] == "gold" and train["ranked"] is True
    # the long text cell wraps at its words (on one line it pushed the table past the
    # card's right edge): app.css's td.words
    cells = re.findall(r'<td class="([^"]*)">' + re.escape(html.escape(SAMPLING)), text)
    assert cells == ["num mono words"] * 3, cells


def test07_select_marks_no_cheapest_rung_that_fails(client: TestClient, settings: Settings) -> None:
    """The select table highlighted its cheapest rung (the cost column's lowest) in green
    though that rung fails the target; the chosen rung is the one its table says."""
    text, data = page(client, settings, "select")
    assert data["rows"]["analytic"]["meets"] is False and data["rows"]["hybrid 16x3"]["chosen"]
    assert data["best"] == {} and 'class="num mono best"' not in text
