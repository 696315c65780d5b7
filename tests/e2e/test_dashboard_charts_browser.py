"""Issue 26 §1: every kind that writes ``curves.json`` or ``pareto.json`` gets its charts drawn,
in headless Chromium: its job page, and the compare view of two of its jobs, show a chart
with at least one visible data point per series (per panel for the compare view's menus).

The kinds are found from the registry (every kind whose artifacts name ``curves.json`` or
``pareto.json``), so a new one is tested too. Each is run twice with its own smoke params
(seeds 0 and 1; the inputs are the smoke runs of the kinds they name, as
``tests/integration/test_kinds_smoke.py`` makes them). Screenshots:
``/tmp/matforge-charts-<kind>.png`` and ``/tmp/matforge-charts-<kind>-compare.png``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import pytest

from service import kinds
from service.cli.batch import substitute_refs
from service.settings import Settings
from service.specs import STEP_REF
from service.submission import run_in_process
from storage.jobs import Job

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings

pytestmark = BROWSER

CHARTED = ("curves.json", "pareto.json")
#: The kinds that write a chart document, and which.
KINDS = {
    k.name: next(n for n in CHARTED if n in k.artifacts)
    for k in sorted(kinds.all_kinds().values(), key=lambda k: k.name)
    if any(n in k.artifacts for n in CHARTED) and k.smoke
}

#: Per dataset of a Chart.js chart: how many of its points are visible, i.e. inside the
#: chart area and drawn as a dot (radius > 0), or joined by a line to another such point.
VISIBLE = """canvas => {
  const chart = Chart.getChart(canvas);
  if (!chart) return null;
  const a = chart.chartArea;
  return chart.data.datasets.map((d, i) => {
    const meta = chart.getDatasetMeta(i);
    const inside = meta.data.filter((e, j) => d.data[j] && d.data[j].y !== null
      && isFinite(e.x) && isFinite(e.y) && e.x >= a.left - 0.5 && e.x <= a.right + 0.5
      && e.y >= a.top - 0.5 && e.y <= a.bottom + 0.5);
    const dots = inside.filter(e => e.options && e.options.radius > 0).length;
    const line = (d.type || chart.config.type) === "line" && d.borderWidth > 0
      && inside.length >= 2 ? inside.length : 0;
    return {label: d.label, hidden: meta.hidden, visible: Math.max(dots, line)};
  });
}"""


#: Every tick label of every chart on the page (numeric axes only).
TICK_LABELS = """() => [...document.querySelectorAll("canvas")].flatMap(c => {
  const ch = Chart.getChart(c);
  if (!ch) return [];
  return Object.values(ch.scales).filter(s => s.type !== "category")
    .flatMap(s => s.ticks.map(t => String(t.label === undefined ? "" : t.label)))
    .filter(t => t !== "");
})"""


class Runs:
    """Smoke jobs by kind (seed 0) and their second runs (seed 1), inputs first."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.done: dict[tuple[str, int], Job] = {}

    def job(self, name: str, seed: int = 0) -> Job:
        if (name, seed) not in self.done:
            kind = kinds.get_kind(name)

            def resolve(ref: str) -> str:
                m = STEP_REF.match(ref)
                assert m is not None
                dep = self.job(m["step"])
                assert dep.state == "succeeded", f"{name} needs {m['step']}: {dep.error}"
                return f"job:{dep.id}" if m["name"] is None else f"job:{dep.id}/{m['name']}"

            params: dict[str, Any] = substitute_refs(kind.smoke, resolve)
            spec = {"kind": name, "seed": seed, "name": f"{name} s{seed}", "params": params}
            self.done[name, seed] = run_in_process(spec, self.settings)
        return self.done[name, seed]


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Two finished jobs of every kind that writes a chart document."""
    kinds.load_builtin()
    runs = Runs(data_settings(tmp_path_factory, "dashboard-charts"))
    pairs = {}
    jobs = runs.settings  # the store and jobs database, for the live test below
    for name in KINDS:
        pair = [runs.job(name, 0), runs.job(name, 1)]
        assert all(j.state == "succeeded" for j in pair), [j.error for j in pair]
        pairs[name] = [j.id for j in pair]
    yield {"data": runs.settings.data_dir, "pairs": pairs, "settings": jobs}


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def visible(pg: Any, selector: str) -> list[dict[str, Any]]:
    """Wait for the chart at ``selector`` to have datasets; their visible points."""
    pg.wait_for_function(
        "s => { const c = document.querySelector(s); const ch = c && Chart.getChart(c);"
        " return ch && ch.data.datasets.length > 0 && ch.chartArea; }",
        arg=selector,
    )
    return pg.locator(selector).evaluate(VISIBLE)


def assert_every_series_seen(found: list[dict[str, Any]], where: str) -> None:
    assert found, f"{where}: no series"
    unseen = [d["label"] for d in found if d["hidden"] or d["visible"] < 1]
    assert not unseen, f"{where}: series with no visible point: {unseen} ({found})"


def test_the_charted_kinds_are_all_here() -> None:
    # the kinds known to write them today; a new one joins the parametrised tests below
    assert {"train.brdf", "train.btf", "train.fabric"} <= {
        k for k, n in KINDS.items() if n == "curves.json"
    }
    assert {"report.brdf", "report.pareto"} <= {k for k, n in KINDS.items() if n == "pareto.json"}


@pytest.mark.parametrize("kind", list(KINDS))
def test_job_page_draws_the_chart(
    page: Any, server: str, prepared: dict[str, Any], kind: str
) -> None:
    pg = page
    job_id = prepared["pairs"][kind][0]
    pg.goto(f"{server}/jobs/{job_id}?token={TOKEN}")
    plots = pg.locator("#plots")
    if KINDS[kind] == "curves.json":
        found = visible(pg, "#curves-chart")
        assert_every_series_seen(found, f"{kind} job page")
        names = {d["label"] for d in found}
        assert "epoch" not in names and ("loss" in names or "train_loss" in names), names
    else:
        charts = pg.locator("#plots canvas")
        pg.wait_for_function("() => document.querySelectorAll('#plots canvas').length > 0")
        assert charts.count() >= 1
        for i in range(charts.count()):
            found = charts.nth(i).evaluate(VISIBLE)
            assert_every_series_seen(found, f"{kind} job page, chart {i}")
        # §5: no per-column bars under the Pareto panels (ns and bytes on one axis before)
        assert pg.locator("#metrics-charts canvas").count() == 0
    assert "cannot draw" not in plots.inner_text()
    # §5: tick labels in SI prefixes (1 µ, 1.53 MB), never 1.00000000000000E-6 or 1.528e+06
    labels = pg.evaluate(TICK_LABELS)
    assert labels, f"{kind}: no tick labels"
    raw = [t for t in labels if re.search(r"\d[eE][+-]?\d", t) or len(t) > 12]
    assert not raw, f"{kind}: tick labels not in SI form: {raw}"
    plots.scroll_into_view_if_needed()
    pg.screenshot(path=str(SHOTS / f"matforge-charts-{kind}.png"), full_page=True)
    assert pg.problems == [], pg.problems


@pytest.mark.parametrize("kind", list(KINDS))
def test_compare_view_overlays_two_jobs(
    page: Any, server: str, prepared: dict[str, Any], kind: str
) -> None:
    pg = page
    ids = prepared["pairs"][kind]
    pg.goto(f"{server}/compare?jobs={','.join(ids)}&token={TOKEN}")
    menu, chart = (
        ("#c-series", "#c-curves-chart")
        if KINDS[kind] == "curves.json"
        else ("#c-panel", "#c-pareto-chart")
    )
    visible(pg, chart)
    options = pg.locator(f"{menu} option").all_inner_texts()
    assert options, f"{kind}: an empty {menu} menu"
    for option in options:
        pg.select_option(menu, option)
        found = visible(pg, chart)
        assert_every_series_seen(found, f"{kind} compare view, {option}")
        title = pg.locator(chart).evaluate("c => Chart.getChart(c).options.plugins.title.text")
        assert title.startswith(f"{option}: 2 "), title  # both jobs in every series
    pg.select_option(menu, options[0])
    pg.locator(chart).scroll_into_view_if_needed()
    pg.screenshot(path=str(SHOTS / f"matforge-charts-{kind}-compare.png"), full_page=True)
    assert pg.problems == [], pg.problems


def test_live_train_brdf_curves_old_and_new(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """A running train.brdf job's page draws its live curves (the kind publishes them), in
    the one schema with its two phases, and a document of before the schema (phases under
    ``train`` and ``heldout``, as such a job's curves.json is) too, as the same points."""
    import json

    from jobapi.context import LIVE_PREFIX
    from jobapi.documents import check_curves
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    settings: Settings = prepared["settings"]
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    try:
        job, _ = jobs.submit(kind="train.brdf", name="live", seed=99, spec_hash="d" * 64,
                             spec={"kind": "train.brdf", "params": {}})  # fmt: skip
        claimed = jobs.claim("test-host:1", 120.0, job_id=job.id)
        assert claimed is not None and claimed.lease_token
        old = {
            "train": {"step": [1, 2, 3], "loss": [3.0, 2.0, 1.5], "lr": [0.1, 0.1, 0.05]},
            "heldout": {"step": [1, 2], "loss": [2.5, 2.0], "lr": [0.1, 0.1]},
        }
        new = {
            "step": [1, 2, 3, 4, 5],
            "loss": [3.0, 2.0, 1.5, 2.5, 2.0],
            "lr": [0.1, 0.1, 0.05, 0.1, 0.1],
            "phases": [
                {"name": "train", "first_step": 1, "last_step": 3},
                {"name": "heldout", "first_step": 4, "last_step": 5},
            ],
        }
        check_curves(new)
        pg = page
        drawn = (
            "() => { const c = Chart.getChart(document.getElementById('curves-chart'));"
            " return c && c.data.datasets.length ? c.data.datasets.map(d => [d.label,"
            " d.data.map(p => [p.x, p.y])]) : null; }"
        )
        seen = []
        for doc in (new, old):
            info = store.put_bytes(json.dumps(doc).encode())
            jobs.record_shard(job.id, LIVE_PREFIX + "curves.json", info.digest)
            pg.goto(f"{server}/jobs/{job.id}?token={TOKEN}")
            pg.wait_for_function(drawn)
            assert_every_series_seen(pg.locator("#curves-chart").evaluate(VISIBLE), "live")
            seen.append(pg.evaluate(drawn))
        assert seen[0] == seen[1]
        assert seen[0][0] == [
            "loss",
            [[s, v] for s, v in zip(new["step"], new["loss"], strict=True)],
        ]
        pg.screenshot(path=str(SHOTS / "matforge-charts-train.brdf-live.png"), full_page=True)
        jobs.cancel(job.id)
        assert pg.problems == [], pg.problems
    finally:
        jobs.close()
