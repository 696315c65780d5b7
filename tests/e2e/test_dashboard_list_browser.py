"""The job list and result tables in headless Chromium (issue 14 §3): search by name,
sortable columns, paging past 200 jobs, an unknown filter named in the page, and a
train.fabric-sized metrics table that stays on the page.

The server, the browser page and its problem log come from :mod:`tests.e2e.browser`; this
module prepares its own data directory (230 jobs) and registers its own test kind in the
server process.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pydantic import Field

from evaluators.metrics.tonemap import tonemap
from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Axis, Figure, Kind
from jobapi.params import StrictModel
from service import kinds
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png
from storage.jobs import JobStore
from tests.helpers.job_documents import fabric_metrics

from .browser import BROWSER, SHOTS, TICK_BOXES, TOKEN, browser_server, data_settings

pytestmark = BROWSER

N_QUEUED = 230
#: The run of the chart's beaten point: clicking it opens this job's page (there is none).
OTHER_RUN = "job:" + "ab" * 16


class WideParams(StrictModel):
    """Params of the test-only kind."""

    size: int = Field(default=16, ge=4, le=64, description="preview side in pixels")


def run_wide(params: WideParams, ctx: JobContext) -> None:
    """A tiny preview and a metrics.json laid out as train.fabric writes it (every column)."""
    from models.fabric.kind import FABRIC_COLUMNS

    s = params.size
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    ctx.put_bytes("slice.png", write_png(None, tonemap(np.stack([x, y, x * y], axis=-1))))
    y, x = np.mgrid[0:100, 0:400].astype(np.float32) / 400
    ctx.put_bytes("preview.png", write_png(None, tonemap(np.stack([x, x, y], axis=-1))))
    hdr = np.stack([x, y, 1 - x], axis=-1).astype(np.float32) * (s / 16.0) ** 2
    ctx.put_bytes("image.exr", exr_bytes(hdr[:, ::8][:24] * 4.0))  # (24, 50, 3) linear

    def material(i: int, name: str) -> dict[str, Any]:
        values: dict[str, Any] = {"name": name, "pattern": "twill_3x3_long_pattern_name"}
        for j, col in enumerate(FABRIC_COLUMNS[1:]):
            values[col] = 1234.5678 * (i + 1) / (j + 1)
        values["queries"] = 20480  # the same for every material: no chart
        return values

    steps = list(range(10, 210, 10))
    ctx.put_json(
        "curves.json",
        {
            "step": steps,
            "loss": [10.0 / k for k in steps],
            "mse": {"C_warp": [1.0 / k for k in steps], "S_warp": [2.0 / k for k in steps]},
            "lr": [1e-3 * 0.99**k for k in steps],
        },
    )
    run = f"job:{ctx.job_id}"
    ctx.put_json(
        "pareto.json",
        {  # the one pareto.json schema (docs/artifacts.md): panels of points
            "format": "matforge.pareto/1",
            "runs": [run, OTHER_RUN],
            "panels": [{
                "dataset": None, "scene": None, "metric": "smape", "cost": "ns_per_eval",
                "cost_label": "ns_per_eval", "front": ["hybrid 16x3", "hybrid 32x3"],
                "points": [
                    {"candidate": "hybrid 16x3", "cost": 2.0, "mean": 0.20, "std": 0.02,
                     "front": True, "jobs": [run]},
                    {"candidate": "hybrid 32x3", "cost": 100.0, "mean": 0.12, "std": 0.01,
                     "front": True, "jobs": [run]},
                    {"candidate": "neural 16x3", "cost": 30.0, "mean": 0.30, "std": 0.05,
                     "front": False, "jobs": [OTHER_RUN]},
                ],
            }],
        },
    )  # fmt: skip
    mats = [material(i, f"fabric_material_with_a_long_name_{i}") for i in range(3)]
    mean = {k: v for k, v in material(9, "mean").items() if k not in ("name", "pattern")}
    # train.fabric's whole metrics.json (its summary reads it typed)
    ctx.put_json("metrics.json", fabric_metrics(mats, mean))


def wide_kind() -> Kind:
    """The test-only kind (the server registers it too: its page asks the summary hook)."""
    from models.fabric.kind import summarize

    return Kind(
        name="test_wide",
        params=WideParams,
        runner=run_wide,
        description="test-only kind with train.fabric's result table",
        artifacts=("preview.png", "slice.png", "image.exr", "curves.json", "pareto.json"),
        summary=summarize,
        figures=(
            Figure("preview.png", caption="the lead picture", lead=True),
            Figure("slice*.png", x=Axis("θh", "0°", "90°"), y=Axis("θd", "0°", "90°")),
        ),
    )


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """One finished ``test_wide`` job and 230 queued jobs named ``sample NNN``."""
    kinds.load_builtin()
    kind = wide_kind()
    jobapi_kinds.register(kind)
    settings = data_settings(tmp_path_factory, "dashboard-list")
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    try:
        done, _ = submit({"kind": kind.name, "name": "wide table", "params": {}}, jobs, store)
        assert run_worker(settings, max_jobs=1) == 1
        for i in range(N_QUEUED):
            jobs.submit(
                kind="render",
                name=f"sample {i:03d}" if i % 10 else f"Special sample {i:03d}",
                seed=i,
                spec_hash=f"{i:064x}",
                spec={"kind": "render", "seed": i, "params": {}}
                | ({"batch": "nightly 2026-12-01"} if i >= N_QUEUED - 5 else {}),
            )
        # the finished job ran 119.6 s: the list and its page say "2 min 00 s"
        jobs._conn().execute(
            "UPDATE jobs SET started_at = finished_at - 119.6 WHERE id = ?", (done.id,)
        )
        jobs._conn().commit()
        yield {"data": settings.data_dir, "done": jobs.get(done.id), "jobs": jobs}
    finally:
        jobs.close()
        jobapi_kinds._KINDS.pop(kind.name, None)


server = browser_server("tests.e2e.test_dashboard_list_browser:wide_kind")


def url_has(pg: Any, part: str) -> None:
    """Wait until the address bar holds ``part``. The page changes it with replaceState,
    which Playwright's ``page.url`` learns of asynchronously, so reading that races."""
    pg.wait_for_function("p => location.href.includes(p)", arg=part)


def row_names(pg: Any) -> list[str]:
    return [n.strip() for n in pg.locator("#jobs-body .job-name").all_inner_texts()]


def test01_search_sort_and_pages(page: Any, server: str) -> None:
    pg = page
    pg.goto(f"{server}/?token={TOKEN}")
    pg.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length > 0")
    assert len(row_names(pg)) == 50
    assert row_names(pg)[0] == "sample 229"
    assert pg.locator("#page-info").inner_text() == f"1–50 of {N_QUEUED + 1}"
    # page past 200 jobs: the oldest appear on the last page
    for _ in range(4):
        pg.click("#page-next")
    pg.wait_for_function("() => document.querySelector('#page-info').textContent.startsWith('201')")
    pg.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length === 31")
    url_has(pg, "page=5")
    assert row_names(pg)[-1] == "wide table"
    assert pg.locator("#page-next").is_disabled()
    # sort by name, ascending then descending
    pg.click('th[data-sort="name"] button')
    pg.wait_for_function("() => document.querySelector('#page-info').textContent.startsWith('1–')")
    pg.wait_for_function(
        "() => document.querySelector('#jobs-body .job-name').textContent === 'sample 001'"
    )
    assert pg.locator('th[data-sort="name"]').get_attribute("aria-sort") == "ascending"
    pg.click('th[data-sort="name"] button')
    pg.wait_for_function(
        "() => document.querySelector('#jobs-body .job-name').textContent === 'wide table'"
    )
    url_has(pg, "sort=-name")
    # search by name (any case, part of it)
    pg.fill("#f-name", "special")
    pg.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length === 23")
    assert all(n.startswith("Special sample") for n in row_names(pg))
    url_has(pg, "name=special")
    assert pg.locator("#page-info").inner_text() == "1–23 of 23"
    pg.screenshot(path=str(SHOTS / "matforge-dashboard-list.png"), full_page=True)
    assert pg.problems == [], pg.problems


def test02_unknown_filter_is_named(page: Any, server: str) -> None:
    page.goto(f"{server}/?kind=scor&token={TOKEN}")
    page.wait_for_function(
        "() => document.querySelector('#status-line').textContent.includes('kind')"
    )
    assert "unknown kind 'scor'" in page.locator("#status-line").inner_text()
    page.problems[:] = [p for p in page.problems if "HTTP 422" not in p and "422" not in p]
    assert page.problems == [], page.problems


def test03_wide_metrics_table_stays_on_the_page(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    page.goto(f"{server}/jobs/{prepared['done'].id}?token={TOKEN}")
    table = page.locator("#metrics-table")
    table.wait_for()
    assert table.locator("thead th").count() >= 10
    fits = page.evaluate(
        """() => {
            const t = document.querySelector('#metrics-table');
            const wrap = t.parentElement;
            return {table: t.scrollWidth, wrap: wrap.clientWidth,
                    doc: document.documentElement.scrollWidth, win: window.innerWidth};
        }"""
    )
    assert fits["table"] <= fits["wrap"] and fits["doc"] <= fits["win"], fits
    page.screenshot(path=str(SHOTS / "matforge-dashboard-wide-table.png"), full_page=True)
    assert page.problems == [], page.problems


def test04_pictures_lead_axes_and_square_pixels(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """Issue 14 §4: the kind's lead picture first at its full size, a plot with labelled
    axes, and no upscaling blur on a small picture."""
    page.goto(f"{server}/jobs/{prepared['done'].id}?token={TOKEN}")
    page.wait_for_function(
        "() => [...document.querySelectorAll('figure img')]"
        ".every(i => i.complete && i.naturalWidth > 0)"
    )
    names = page.locator("figure[data-name]").evaluate_all("fs => fs.map(f => f.dataset.name)")
    assert names[0] == "preview.png", names
    lead = page.locator(".lead img")
    assert lead.evaluate("i => [i.clientWidth, i.naturalWidth]") == [400, 400]
    assert "the lead picture" in page.locator(".lead figcaption").inner_text()
    plot = page.locator('figure[data-name="slice.png"]')
    assert "θh" in plot.locator(".axis-x").inner_text()
    assert "θd" in plot.locator(".axis-y").inner_text()
    assert plot.locator(".axis-x span").first.inner_text() == "0°"
    small = plot.locator("img")
    assert small.evaluate("i => i.naturalWidth < i.clientWidth")
    assert small.evaluate("i => getComputedStyle(i).imageRendering") == "pixelated"
    assert lead.evaluate("i => getComputedStyle(i).imageRendering") != "pixelated"
    page.screenshot(path=str(SHOTS / "matforge-dashboard-pictures.png"), full_page=True)
    assert page.problems == [], page.problems


def test05_group_by_batch_with_thumbnails(page: Any, server: str) -> None:
    page.goto(f"{server}/?token={TOKEN}")
    page.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length > 0")
    page.check("#f-group")
    page.wait_for_function("() => document.querySelectorAll('#jobs-body tr.group').length === 2")
    labels = page.locator("#jobs-body tr.group .group-label").all_inner_texts()
    assert labels == ["nightly 2026-12-01", "not in a batch"]
    url_has(page, "group=1")
    page.locator('tr.group[data-batch="nightly 2026-12-01"] button').click()
    page.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length === 5")
    url_has(page, "batch=nightly")
    assert page.locator("#batch-filter").is_visible()
    assert page.locator("#page-info").inner_text() == "1–5 of 5"
    page.click("#batch-clear")
    page.wait_for_function(
        "() => document.querySelectorAll('#jobs-body tr[data-id]').length === 50"
    )
    # a succeeded job shows its preview as a thumbnail
    page.fill("#f-name", "wide")
    page.wait_for_function(
        "() => { const i = document.querySelector('#jobs-body img.thumb');"
        " return i && i.complete && i.naturalWidth > 0; }"
    )
    assert page.locator("#jobs-body tr[data-id]").count() == 1
    page.screenshot(path=str(SHOTS / "matforge-dashboard-groups.png"), full_page=False)
    assert page.problems == [], page.problems


def test06_charts_fit_the_data(page: Any, server: str, prepared: dict[str, Any]) -> None:
    """Issue 14 §2: no chart for a constant column, a metric's baseline beside it, the best
    row highlighted and the better direction named."""
    page.goto(f"{server}/jobs/{prepared['done'].id}?token={TOKEN}")
    page.locator("#metrics-charts canvas").first.wait_for()
    charts = page.locator("#metrics-charts canvas")
    metrics = charts.evaluate_all("cs => cs.map(c => c.dataset.metric)")
    assert "queries" not in metrics and "pattern" not in metrics  # constant, text
    assert "loss" in metrics and "baseline.loss" not in metrics
    loss = page.locator('canvas[data-metric="loss"]')
    info = loss.evaluate(
        "c => { const ch = Chart.getChart(c); return {sets: ch.data.datasets.map(d => d.label),"
        " title: ch.options.plugins.title.text, best: ch.options.plugins.subtitle.text}; }"
    )
    assert info["sets"] == ["model", "baseline"], info
    assert info["title"] == "loss (lower is better ↓)"
    assert info["best"] == "best: fabric_material_with_a_long_name_0"
    best = page.locator("#metrics-table td.best")
    assert best.count() >= 5
    row = page.locator("#metrics-table tbody tr").first
    assert row.locator("td.best").count() >= 5  # the first material is best on every error
    assert "↓" in page.locator("#metrics-table thead").inner_text()
    assert page.problems == [], page.problems


def test07_curves_and_pareto_charts(page: Any, server: str, prepared: dict[str, Any]) -> None:
    """Issue 14 §2: curves.json and pareto.json drawn with Chart.js: the front highlighted,
    seed spread as error bars, the configuration on hover, its run's job on click."""
    job_id = prepared["done"].id
    page.goto(f"{server}/jobs/{job_id}?token={TOKEN}")
    page.wait_for_function(
        "() => Chart.getChart(document.getElementById('curves-chart'))"
        " && Chart.getChart(document.getElementById('pareto-chart'))"
    )
    sets = page.locator("#curves-chart").evaluate(
        "c => Chart.getChart(c).data.datasets.map(d => d.label)"
    )
    assert sets == ["loss", "mse.C_warp", "mse.S_warp", "lr"]
    scales = page.locator("#curves-chart").evaluate(
        "c => { const s = Chart.getChart(c).scales; return [s.y.type, s.lr.type]; }"
    )
    assert scales == ["logarithmic", "logarithmic"]  # the losses span decades
    pareto = page.locator("#pareto-chart")
    info = pareto.evaluate(
        "c => { const ch = Chart.getChart(c); return {sets: ch.data.datasets.map(d =>"
        " [d.label, d.data.length]), x: ch.scales.x.type}; }"
    )
    assert info["sets"] == [["front", 2], ["on the front", 2], ["beaten", 1]]
    assert info["x"] == "logarithmic"  # 2 to 100 ns: over a decade
    # hover the beaten point: its configuration shows
    where = pareto.evaluate(
        "c => { const ch = Chart.getChart(c); const p = ch.getDatasetMeta(2).data[0];"
        " return {x: p.x, y: p.y}; }"
    )
    pareto.scroll_into_view_if_needed()
    box = pareto.bounding_box()
    assert box is not None
    page.mouse.move(box["x"] + where["x"], box["y"] + where["y"])
    page.wait_for_function(
        "() => Chart.getChart(document.getElementById('pareto-chart'))"
        ".tooltip.getActiveElements().length > 0"
    )
    title = pareto.evaluate("c => Chart.getChart(c).tooltip.title")
    assert title == ["neural 16x3"]
    page.screenshot(path=str(SHOTS / "matforge-pareto.png"), full_page=True)
    assert page.problems == [], page.problems
    # click: the point's run (a job this server does not have: its 404 page)
    page.mouse.click(box["x"] + where["x"], box["y"] + where["y"])
    page.wait_for_url(f"**/jobs/{OTHER_RUN[4:]}", timeout=10_000)
    page.problems.clear()


def test08_live_curves_of_a_running_job(page: Any, server: str, prepared: dict[str, Any]) -> None:
    """Issue 14 §2: a running training job's curves grow on its page."""
    from jobapi.context import LIVE_PREFIX

    jobs: JobStore = prepared["jobs"]
    store = ArtifactStore(prepared["data"] / "store")
    job, _ = jobs.submit(
        kind="test_wide", name="training", seed=99, spec_hash="c" * 64, spec={"params": {}}
    )
    claimed = jobs.claim("test-host:1", 120.0, job_id=job.id)
    assert claimed is not None and claimed.lease_token

    def publish(n: int) -> None:
        doc = {"step": list(range(1, n + 1)), "loss": [1.0 / k for k in range(1, n + 1)]}
        info = store.put_bytes(json.dumps(doc).encode())
        jobs.record_shard(job.id, LIVE_PREFIX + "curves.json", info.digest)

    publish(3)
    page.goto(f"{server}/jobs/{job.id}?token={TOKEN}")
    points = (
        "n => { const c = Chart.getChart(document.getElementById('curves-chart'));"
        " return c && c.data.datasets[0].data.length === n; }"
    )
    page.wait_for_function(points, arg=3)
    publish(7)
    page.wait_for_function(points, arg=7, timeout=10_000)
    title = page.locator("#curves-chart").evaluate(
        "c => Chart.getChart(c).options.plugins.title.text"
    )
    assert title == "Training curves, live: step 7"
    jobs.cancel(job.id)
    assert page.problems == [], page.problems


WIDTHS = [1280, 800]


@pytest.mark.parametrize("width", WIDTHS)
def test06_durations_round_once_and_times_stay_on_one_line(
    page: Any, server: str, prepared: dict[str, Any], width: int
) -> None:
    """A run of 119.6 s reads "2 min 00 s" in the list, as on its page (the list said
    "1 min 60 s"); the creation time is one line (it wrapped as "P" / "M")."""
    page.set_viewport_size({"width": width, "height": 900})
    done = prepared["done"]
    page.goto(f"{server}/?name=wide&token={TOKEN}")
    row = page.locator(f"#jobs-body tr[data-id='{done.id}']")
    row.wait_for()
    assert row.locator("td").last.inner_text().strip() == "2 min 00 s"
    lines = page.evaluate(
        """id => {
          const td = document.querySelector(`#jobs-body tr[data-id='${id}'] td.when`);
          const range = document.createRange();
          range.selectNodeContents(td);
          return new Set([...range.getClientRects()].map((r) => Math.round(r.top))).size;
        }""",
        done.id,
    )
    assert lines == 1, (width, lines)
    page.goto(f"{server}/jobs/{done.id}?token={TOKEN}")
    assert "2 min 00 s" in page.locator("body").inner_text()
    # the page's times wrap between date and clock time only ("3:36:38 P" / "M" before)
    split = page.evaluate(
        """() => [...document.querySelectorAll("time[datetime]")]
          .filter((t) => t.textContent.includes(":")).map((t) => {
          const node = t.firstChild, text = node.textContent, at = text.indexOf(" ") + 1;
          const range = document.createRange();
          range.setStart(node, at);
          range.setEnd(node, text.length);
          return [text, new Set([...range.getClientRects()].map((r) => Math.round(r.top))).size];
        })"""
    )
    assert split and all(lines == 1 for _, lines in split), (width, split)
    assert page.problems == [], page.problems


@pytest.mark.parametrize("width", WIDTHS)
def test07_a_refused_filter_has_no_pager_and_is_asked_once(
    page: Any, server: str, width: int
) -> None:
    """The job list under a refused filter: the error, no pager ("1–21 of 21" stayed under
    it), and no more requests until the filters change (it asked again every second, each
    a 422 in the server's log); a plain visit after it asks nothing refused."""
    page.set_viewport_size({"width": width, "height": 900})
    refused: list[str] = []
    page.on("response", lambda r: refused.append(r.url) if r.status == 422 else None)
    page.goto(f"{server}/?filter=nonsense&token={TOKEN}")
    page.wait_for_function(
        "() => document.querySelector('#status-line').textContent.startsWith('refused')"
    )
    assert page.locator("#pager").is_hidden()
    assert page.locator("#jobs-body td.error").count() == 1
    page.wait_for_timeout(3500)  # three polls' time
    assert len(refused) == 1, refused
    page.goto(f"{server}/?token={TOKEN}")
    page.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length > 0")
    page.wait_for_timeout(2500)
    assert page.locator("#pager").is_visible()
    assert len(refused) == 1, refused
    page.problems[:] = [p for p in page.problems if "422" not in p]
    assert page.problems == [], page.problems


@pytest.mark.parametrize("width", WIDTHS)
def test08_chart_tick_labels_do_not_overlap(
    page: Any, server: str, prepared: dict[str, Any], width: int
) -> None:
    """The job page's charts (its Pareto panels and metric bars): on every numeric axis
    each tick label Chart.js draws clears its neighbours (the brdf, pareto and compare
    pages drew them into each other)."""
    page.set_viewport_size({"width": width, "height": 900})
    page.goto(f"{server}/jobs/{prepared['done'].id}?token={TOKEN}")
    page.wait_for_function("() => document.querySelectorAll('canvas').length > 0")
    page.wait_for_timeout(500)
    axes = page.evaluate(TICK_BOXES)
    assert axes, "no chart axes on the page"
    for axis in axes:
        boxes = sorted(axis["boxes"])
        for (a, wa), (b, wb) in zip(boxes, boxes[1:], strict=False):
            assert b - a >= (wa + wb) / 2 + 2, (width, axis["chart"], axis["axis"], boxes)
    assert page.problems == [], page.problems
