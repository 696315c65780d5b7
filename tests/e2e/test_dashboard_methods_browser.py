"""A report's method x metric table on its job page, in headless Chromium (nerfbaselines
style, as ``matforge results --pivot`` prints it): a ``report.pareto`` over two ``train.brdf``
runs of different widths (16 and 32) shows a row per method, each metric's mean and each
cost, and the best of each column marked, except the timings taken by each job on its own
(``ns_per_eval``), which are shown and named as not ranked.

The reference is the report's own ``rows.json``, averaged here with plain Python (not with
:mod:`service.results_pivot`). Screenshot: ``/tmp/matforge-dashboard-methods.png``.
"""

from __future__ import annotations

import json
import statistics
from collections.abc import Iterator
from typing import Any

import pytest

from service import kinds
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings

pytestmark = BROWSER


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    kinds.load_builtin()
    settings = data_settings(tmp_path_factory, "dashboard-methods")

    def run(spec: dict[str, Any]) -> Job:
        job = run_in_process(spec, settings)
        assert job.state == "succeeded", job.error
        return job

    merl = run({"kind": "generate.merl", "params": kinds.get_kind("generate.merl").smoke})
    smoke = dict(kinds.get_kind("train.brdf").smoke)
    trained = [
        run({"kind": "train.brdf", "params": {**smoke, "dataset": f"job:{merl.id}", "width": w}})
        for w in (16, 32)
    ]
    report = run({"kind": "report.pareto", "params": {"runs": [f"job:{j.id}" for j in trained]}})
    yield {"data": settings.data_dir, "report": report, "store": ArtifactStore(settings.store_dir)}


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def test_methods_table_of_a_report(page: Any, server: str, prepared: dict[str, Any]) -> None:
    pg = page
    report: Job = prepared["report"]
    record = next(a for a in report.artifacts if a.name == "rows.json")
    rows = json.loads(prepared["store"].read(record.digest))
    # the reference: each candidate's mean SMAPE, from the rows themselves
    smape: dict[str, list[float]] = {}
    for r in rows:  # a method is a candidate and its split: "hybrid 16x2 (train)"
        if r["metric"] == "brdf.smape":
            method = f"{r['candidate']} ({r['split']})" if r["split"] else r["candidate"]
            smape.setdefault(method, []).append(r["value"])
    assert len(smape) == 2, smape
    means = {c: statistics.fmean(v) for c, v in smape.items()}
    pg.goto(f"{server}/jobs/{report.id}?token={TOKEN}")
    table = pg.locator("#methods-table")
    table.wait_for()
    heads = table.locator("thead th").evaluate_all("ths => ths.map(t => t.dataset.column || '')")
    assert "brdf.smape" in heads and "ns_per_eval" in heads, heads
    col = heads.index("brdf.smape")
    shown = table.locator("tbody tr").evaluate_all(
        "trs => trs.map(tr => [tr.dataset.method, [...tr.cells].map(c => c.textContent),"
        " [...tr.cells].map(c => c.classList.contains('best'))])"
    )
    assert {m for m, _, _ in shown} == set(means)
    for method, cells, best in shown:
        assert float(cells[col].split(" ")[0]) == pytest.approx(means[method], rel=1e-3)
        assert best[col] == (means[method] == min(means.values())), (method, cells, best)
        ns = cells[heads.index("ns_per_eval")]  # a cost in SI units: "13.13 ns", never 1.3e+01
        assert ns == "" or (ns.endswith("s") and "e+" not in ns and "e-" not in ns), ns
        # each training job's own timing: shown, never ranked against the other job's
        assert not best[heads.index("ns_per_eval")], (method, cells, best)
    note = pg.locator("#methods-unranked")
    assert "ns_per_eval" in note.locator("[data-column]").all_text_contents()
    assert "one pass" in note.inner_text()
    pg.screenshot(path=str(SHOTS / "matforge-dashboard-methods.png"), full_page=True)
    assert pg.problems == [], pg.problems


#: The report's ns_per_eval chart: each drawn point's cost bar ends, in data and in pixels.
COST_BARS = """() => {
  const canvas = [...document.querySelectorAll("#plots canvas")]
    .find(c => (c.dataset.panel || "").endsWith("ns_per_eval"));
  if (!canvas) return null;
  const chart = Chart.getChart(canvas);
  const a = chart.chartArea;
  return chart.data.datasets.filter(d => d.type !== "line").flatMap(d => d.data.map(p => ({
    candidate: p.point.candidate, xMin: p.xMin, xMax: p.xMax,
    left: chart.scales.x.getPixelForValue(p.xMin), right: chart.scales.x.getPixelForValue(p.xMax),
    inside: [a.left - 0.5, a.right + 0.5]})));
}"""


def test_pareto_chart_draws_the_timing_spread(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """The report's ns_per_eval panel comes from its own timing pass: the chart's points
    carry the pass's min..max as x error bars, inside the plot, and the tooltip names the
    ratio to the reference kernel."""
    pg = page
    report: Job = prepared["report"]
    record = next(a for a in report.artifacts if a.name == "pareto.json")
    doc = json.loads(prepared["store"].read(record.digest))
    panel = next(p for p in doc["panels"] if p["cost"] == "ns_per_eval")
    want = {p["candidate"]: (p["cost_min"], p["cost_max"]) for p in panel["points"]}
    pg.goto(f"{server}/jobs/{report.id}?token={TOKEN}")
    pg.wait_for_function("() => document.querySelectorAll('#plots canvas').length > 0")
    bars = pg.evaluate(COST_BARS)
    assert bars, "no ns_per_eval chart"
    assert {b["candidate"]: (b["xMin"], b["xMax"]) for b in bars} == want
    for b in bars:
        lo, hi = b["inside"]
        assert lo <= b["left"] <= b["right"] <= hi, b
    assert pg.problems == [], pg.problems
