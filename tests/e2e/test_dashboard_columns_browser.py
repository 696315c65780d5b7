"""The job list's parameter and metric columns and filters, in headless Chromium: columns
chosen in the page (``params.model``, ``metric.smape_mean``) show each job's value, filters
(``params.model=hybrid``, ``metric.smape_mean<0.1``) keep the jobs that pass, both are kept
in the address and come back from it, a bad filter is named in the page; and the list, with
its extra columns, long names and long error messages, fits its card at 1280, 1440 and
1920 px, flat and grouped by batch (the Time column never cut, nothing scrolls sideways).

The reference for each value is the job's own spec and the metric it was built to have
(:func:`metric_of`), not the page's arithmetic. The server, the browser page and its problem
log come from :mod:`tests.e2e.browser`. Screenshots:
``/tmp/matforge-dashboard-columns*.png``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from pydantic import Field

from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from jobapi.rows import RowSource, base_row
from service import kinds
from service.submission import submit
from service.workers.worker import run_worker
from storage.jobs import JobStore

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings

pytestmark = BROWSER

KIND = "test_columns"
#: (model, width) of the finished jobs.
RUNS = [("hybrid", 8), ("hybrid", 32), ("neural", 16), ("neural", 64)]
LONG = "a_very_long_material_name_that_goes_on_and_on_" * 3


class ColumnParams(StrictModel):
    """Params of the test-only kind."""

    model: str = Field(default="hybrid", description="a model name")
    width: int = Field(default=16, ge=1, le=1024, description="a width")


def metric_of(model: str, width: int) -> float:
    """The SMAPE a job of these params reports (0.05 for hybrid 32: below 0.1)."""
    return round((0.4 if model == "hybrid" else 0.9) * 4.0 / width, 6)


def run_columns(params: ColumnParams, ctx: JobContext) -> None:
    ctx.put_json("metrics.json", {"smape": metric_of(params.model, params.width)})


def column_rows(src: RowSource) -> list[Any]:
    doc = src.read("metrics.json") or {}
    return [base_row(src, "smape_mean", float(doc["smape"]), candidate="model")]


def columns_kind() -> Kind:
    """The test-only kind (the server registers it too: its rows give the metric columns)."""
    return Kind(
        name=KIND,
        params=ColumnParams,
        runner=run_columns,
        description="test-only kind with a result row",
        artifacts=("metrics.json",),
        rows=column_rows,
        metrics=("smape_mean",),  # declared: metric.smape_mean is a column of this kind
    )


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Four finished jobs with params and a metric, queued jobs with long names in a batch,
    and failed jobs with long one-line errors."""
    kinds.load_builtin()
    kind = columns_kind()
    jobapi_kinds.register(kind)
    settings = data_settings(tmp_path_factory, "dashboard-columns")
    jobs = JobStore(settings.db_path)
    from storage.artifacts import ArtifactStore

    store = ArtifactStore(settings.store_dir)
    try:
        done = {}
        for model, width in RUNS:
            spec = {"kind": KIND, "name": f"{model} {width}", "params": {"model": model,
                    "width": width}}  # fmt: skip
            done[model, width], _ = submit(spec, jobs, store)
        assert run_worker(settings, max_jobs=len(RUNS)) == len(RUNS)
        for i in range(3):
            failed, _ = jobs.submit(
                kind="render", name=f"failed {LONG}{i}", seed=100 + i, spec_hash=f"f{i:063x}",
                spec={"kind": "render", "seed": 100 + i, "params": {"material": LONG}},
            )  # fmt: skip
            claimed = jobs.claim("test-host:1", 60.0, job_id=failed.id)
            assert claimed is not None and claimed.lease_token
            jobs.fail(failed.id, claimed.lease_token, "RuntimeError: " + "unreferenced " * 40)
        for i in range(4):
            jobs.submit(
                kind="render", name=f"{LONG}{i}", seed=i, spec_hash=f"{i:064x}",
                spec={"kind": "render", "seed": i, "params": {"material": LONG},
                      "batch": "nightly " + LONG},
            )  # fmt: skip
        assert all(jobs.get(j.id).state == "succeeded" for j in done.values())
        yield {"data": settings.data_dir, "done": {k: jobs.get(j.id) for k, j in done.items()}}
    finally:
        jobs.close()
        jobapi_kinds._KINDS.pop(kind.name, None)


server = browser_server("tests.e2e.test_dashboard_columns_browser:columns_kind")


def url_has(pg: Any, part: str) -> None:
    pg.wait_for_function("p => location.href.includes(p)", arg=part)


def rows_shown(pg: Any, n: int) -> None:
    pg.wait_for_function(
        "n => document.querySelectorAll('#jobs-body tr[data-id]').length === n", arg=n
    )


def cells(pg: Any, key: str) -> dict[str, str]:
    """Job name -> the text of its cell in column ``key``."""
    out: dict[str, str] = pg.evaluate(
        """key => Object.fromEntries([...document.querySelectorAll('#jobs-body tr[data-id]')]
            .map(r => [r.querySelector('.job-name').textContent,
                       r.querySelector(`td[data-column="${key}"]`).textContent]))""",
        key,
    )
    return out


def test01_columns_and_filters_from_the_page(page: Any, server: str) -> None:
    pg = page
    pg.goto(f"{server}/?token={TOKEN}")
    rows_shown(pg, len(RUNS) + 7)
    pg.fill("#f-columns", "params.model, params.width, metric.smape_mean")
    pg.click("#columns-apply")
    pg.wait_for_function(
        "() => document.querySelectorAll('#jobs-body td[data-column=\"metric.smape_mean\"]')"
        ".length > 0 && document.querySelector('#jobs-body td[data-column]').textContent !== ''"
    )
    heads = pg.locator("#jobs-head th.col-value").evaluate_all(
        "ths => ths.map(t => t.dataset.column)"
    )
    assert heads == ["params.model", "params.width", "metric.smape_mean"]
    # the chosen columns sit before the message: the Time column is still the last
    last = pg.locator("#jobs-head th").last.inner_text()
    assert "TIME" in last.upper(), last
    url_has(pg, "columns=params.model%2Cparams.width%2Cmetric.smape_mean")
    pg.wait_for_function(
        "() => [...document.querySelectorAll('#jobs-body td[data-column=\"metric.smape_mean\"]')]"
        ".filter(td => td.textContent !== '–').length === 4"
    )
    smape = cells(pg, "metric.smape_mean")
    models = cells(pg, "params.model")
    for model, width in RUNS:
        name = f"{model} {width}"
        assert models[name] == model
        assert cells(pg, "params.width")[name] == str(width)
        assert float(smape[name]) == pytest.approx(metric_of(model, width), rel=1e-3)  # 4 digits
    assert all(smape[n] == "–" for n in smape if n.startswith(("failed", "a_very")))  # no rows
    # filter: params and a metric bound, both in the address
    pg.fill("#f-filter", "params.model=hybrid, metric.smape_mean<0.1")
    pg.click("#columns-apply")
    rows_shown(pg, 1)
    assert list(cells(pg, "params.model")) == ["hybrid 32"]
    url_has(pg, "filter=params.model%3Dhybrid&filter=metric.smape_mean%3C0.1")
    assert "2 filter(s)" in pg.locator("#filter-info").inner_text()
    assert pg.locator("#page-info").inner_text() == "1–1 of 1"
    pg.screenshot(path=str(SHOTS / "matforge-dashboard-columns.png"), full_page=True)
    # one filter only: both hybrid runs
    pg.fill("#f-filter", "params.model=hybrid")
    pg.click("#columns-apply")
    rows_shown(pg, 2)
    assert set(cells(pg, "params.model")) == {"hybrid 8", "hybrid 32"}
    # remove a column from its header
    pg.locator('th[data-column="params.width"] button.col-remove').click()
    pg.wait_for_function("() => !document.querySelector('th[data-column=\"params.width\"]')")
    assert pg.locator('#jobs-body td[data-column="params.width"]').count() == 0
    url_has(pg, "columns=params.model%2Cmetric.smape_mean&")
    assert pg.locator("#f-columns").input_value() == "params.model, metric.smape_mean"
    assert pg.problems == [], pg.problems


def test02_the_view_comes_back_from_its_address(page: Any, server: str) -> None:
    pg = page
    pg.goto(
        f"{server}/?columns=metric.smape_mean&filter=params.model!%3Dhybrid"
        f"&filter=metric.smape_mean%3E%3D0.05&sort=name&token={TOKEN}"
    )
    rows_shown(pg, 2)
    got = cells(pg, "metric.smape_mean")
    assert list(got) == ["neural 16", "neural 64"]  # sorted by name, as asked
    assert float(got["neural 16"]) == pytest.approx(metric_of("neural", 16), rel=1e-3)
    assert pg.locator("#f-filter").input_value() == "params.model!=hybrid, metric.smape_mean>=0.05"
    assert pg.locator("#f-columns").input_value() == "metric.smape_mean"
    assert pg.problems == [], pg.problems


def test03_a_bad_filter_is_named(page: Any, server: str) -> None:
    pg = page
    pg.goto(f"{server}/?filter=metric.smape_mean%3Clow&token={TOKEN}")
    pg.wait_for_function(
        "() => document.querySelector('#status-line').textContent.includes('needs a number')"
    )
    text = pg.locator("#jobs-body td.error").inner_text()
    assert "metric.smape_mean<low" in text and "needs a number" in text, text
    pg.problems[:] = [p for p in pg.problems if "422" not in p]
    assert pg.problems == [], pg.problems


@pytest.mark.parametrize("width", [1280, 1440, 1920])
@pytest.mark.parametrize("grouped", [False, True])
def test04_the_list_fits_its_card(page: Any, server: str, width: int, grouped: bool) -> None:
    """Issue: the Time column was cut at 1280, 1440 and 1920 px, and the grouped view
    scrolled sideways so that "not in a batch" read "in a batch". With four extra columns
    (one of them long text),
    long names and long errors, the table is no wider than its card, and the Time cell of
    every row and the whole group label lie inside the card."""
    pg = page
    pg.set_viewport_size({"width": width, "height": 900})
    cols = "params.model,params.material,params.width,metric.smape_mean"
    pg.goto(f"{server}/?columns={cols}{'&group=1' if grouped else ''}&token={TOKEN}")
    rows_shown(pg, len(RUNS) + 7)
    pg.wait_for_function(
        "() => [...document.querySelectorAll('#jobs-body td[data-column=\"metric.smape_mean\"]')]"
        ".filter(td => td.textContent !== '–').length === 4"
    )
    fit = pg.evaluate(
        """() => {
            const t = document.querySelector('#jobs-table');
            const wrap = t.parentElement.getBoundingClientRect();
            const outside = (e) => { const b = e.getBoundingClientRect();
                return b.width === 0 || b.left < wrap.left - 0.5 || b.right > wrap.right + 0.5; };
            const times = [...t.querySelectorAll('tbody tr[data-id] td:last-child')];
            const labels = [...t.querySelectorAll('tbody tr.group .group-label')];
            return {table: t.scrollWidth, wrap: t.parentElement.clientWidth,
                    scroll: t.parentElement.scrollWidth,
                    doc: document.documentElement.scrollWidth, win: window.innerWidth,
                    timeHead: outside(t.querySelector('thead th:last-child')),
                    timesOut: times.filter(outside).length, times: times.length,
                    labelsOut: labels.filter(outside).length, labels: labels.length,
                    messages: [...t.querySelectorAll('td.message')].map(
                        m => m.scrollWidth > m.clientWidth).filter(Boolean).length};
        }"""
    )
    assert fit["table"] <= fit["wrap"] and fit["scroll"] <= fit["wrap"], fit
    assert fit["doc"] <= fit["win"], fit
    assert not fit["timeHead"] and fit["timesOut"] == 0 and fit["times"] == len(RUNS) + 7, fit
    assert fit["messages"] >= 3, fit  # the long errors are cut (ellipsis), not the table
    if grouped:
        assert fit["labels"] == 2 and fit["labelsOut"] == 0, fit
        label = pg.locator("#jobs-body tr.group .group-label").last.inner_text()
        assert label == "not in a batch"
    name = f"matforge-dashboard-columns-{width}{'-grouped' if grouped else ''}.png"
    pg.screenshot(path=str(SHOTS / name), full_page=False)
    assert pg.problems == [], pg.problems
