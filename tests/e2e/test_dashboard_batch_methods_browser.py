"""A batch's method x metric table in its compare view, in headless Chromium (nerfbaselines
style, as ``matforge results --pivot`` prints it for the batch): a batch of a
``generate.merl`` and two ``train.brdf`` runs of different widths (16 and 32) shows on
``/compare?batch=`` a row per method, each metric's mean and each cost's median, and the
best of each column marked, except the timings (each job's own), which are named as not
ranked.

The reference is the batch's jobs' own result rows (:func:`service.results.job_rows`, what
``GET /api/results`` answers), grouped and averaged here with plain Python (not with
:mod:`service.results_pivot`). Screenshot: ``/tmp/matforge-dashboard-batch-methods.png``.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterator
from typing import Any

import pytest

from jobapi.rows import TIMED_COLUMNS
from service import kinds
from service.results import job_rows
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.jobs import Job, JobStore

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings

pytestmark = BROWSER

BATCH = "widths"


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    kinds.load_builtin()
    settings = data_settings(tmp_path_factory, "dashboard-batch-methods")

    def run(spec: dict[str, Any]) -> Job:
        job = run_in_process({**spec, "batch": BATCH}, settings)
        assert job.state == "succeeded", job.error
        return job

    merl = run({"kind": "generate.merl", "name": "data",
                "params": kinds.get_kind("generate.merl").smoke})  # fmt: skip
    smoke = dict(kinds.get_kind("train.brdf").smoke)
    trained = [
        run({"kind": "train.brdf", "name": f"w{w}",
             "params": {**smoke, "dataset": f"job:{merl.id}", "width": w}})
        for w in (16, 32)
    ]  # fmt: skip
    store = ArtifactStore(settings.store_dir)
    queue = JobStore(settings.db_path)
    rows = []
    for job in (merl, *trained):  # a row's method: its candidate, else its job's (step)
        got = job_rows(queue.get(job.id), queue, store)  # name, and its split if any; a
        splits = {r.candidate: r.split for r in got if r.split}  # speed row: its split's
        for r in got:  # (one split here: every material of these runs is a training one)
            split = r.split or splits.get(r.candidate)
            method = str(r.candidate or job.name) + (f" ({split})" if split else "")
            rows.append({**r.document(), "method": method})
    yield {"data": settings.data_dir, "rows": rows}


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def test_methods_table_of_a_batch(page: Any, server: str, prepared: dict[str, Any]) -> None:
    pg = page
    rows: list[dict[str, Any]] = prepared["rows"]
    # the reference, by hand: each method's values of each metric and its train_seconds
    values: dict[tuple[str, str], list[float]] = {}
    lower: dict[str, bool | None] = {}
    train_s: dict[str, list[float]] = {}
    for r in rows:
        values.setdefault((r["method"], r["metric"]), []).append(r["value"])
        lower.setdefault(r["metric"], r["lower_is_better"])
        if r.get("train_seconds") is not None and r["metric"] != "train_seconds":
            train_s.setdefault(r["method"], []).append(r["train_seconds"])
    methods = list(dict.fromkeys(m for m, _ in values))
    # each run's own model (16 and 32 wide), and what both runs also fit (a shared baseline)
    candidates = [m for m in methods if m.startswith(("hybrid 16x", "hybrid 32x"))]
    assert len(candidates) == 2 and len(methods) >= 3, methods
    means = {key: statistics.fmean(v) for key, v in values.items()}
    assert lower.get("brdf.smape") is True, lower

    pg.goto(f"{server}/compare?batch={BATCH}&token={TOKEN}")
    table = pg.locator("#c-methods #methods-table")
    table.wait_for()
    heads = table.locator("thead th").evaluate_all("ths => ths.map(t => t.dataset.column || '')")
    shown = table.locator("tbody tr").evaluate_all(
        "trs => trs.map(tr => [tr.dataset.method, [...tr.cells].map(c => c.textContent),"
        " [...tr.cells].map(c => c.classList.contains('best')),"
        " [...tr.cells].map(c => c.dataset.value ?? null)])"
    )
    by_method = {m: (cells, best) for m, cells, best, _ in shown}
    raw = {m: values for m, _, _, values in shown}
    assert list(by_method) == methods, (list(by_method), methods)
    assert "train_seconds" in heads, heads
    checked = 0
    for metric, lib in lower.items():
        col = heads.index(metric)
        having = {m: means[(m, metric)] for m in methods if (m, metric) in means}
        target = (min if lib else max)(having.values()) if lib is not None else None
        for method, (cells, best) in by_method.items():
            if method not in having:
                assert cells[col] == "", (metric, method, cells)
                continue
            # the raw mean rides along in data-value (the text has SI prefixes and units:
            # "1.767 µs"); summed in another order than the hand mean, hence rel 1e-9
            got = float(raw[method][col])
            assert got == pytest.approx(having[method], rel=1e-9), (metric, method, cells)
            if metric.endswith(("_ns", "seconds")) or "bytes" in metric:  # has a unit
                assert "e+" not in cells[col] and "e-" not in cells[col], (metric, cells)
            # a timing (fused_kernel_ns, ...) is each job's own: shown, never ranked
            timed = metric in TIMED_COLUMNS
            marked = len(having) > 1 and target is not None and having[method] == target
            assert best[col] == (marked and not timed), (metric, method, cells, best)
            checked += 1
    assert checked >= 4, (checked, heads)  # at least two metrics of both candidates
    col = heads.index("train_seconds")
    assert set(candidates) <= set(train_s), train_s
    for method, seconds in train_s.items():  # a run's own cost; a baseline's: the median
        cells, _ = by_method[method]
        want = statistics.median(seconds)
        # shown with an SI prefix and its unit (e.g. "850 ms", "1.234 s"); the raw value
        # rides along in data-value
        assert float(raw[method][col]) == pytest.approx(want, rel=1e-9), (method, cells)
        assert cells[col].endswith("s") and "e+" not in cells[col], (method, cells)
    unranked = pg.locator("#c-methods #methods-unranked [data-column]").all_text_contents()
    assert "train_seconds" in unranked, unranked
    assert all(u.removeprefix("cost.") in TIMED_COLUMNS for u in unranked), unranked
    # the pictures of the batch are still there, above the table
    pg.locator("#compare-grid figure").first.wait_for()
    pg.locator("#c-methods").scroll_into_view_if_needed()
    pg.screenshot(path=str(SHOTS / "matforge-dashboard-batch-methods.png"), full_page=True)
    assert pg.problems == [], pg.problems


def test_the_batch_group_links_to_its_table(page: Any, server: str) -> None:
    pg = page
    pg.goto(f"{server}/?group=1&token={TOKEN}")
    link = pg.locator(f'tr.group[data-batch="{BATCH}"] a:text-is("methods table")')
    link.wait_for()
    link.click()
    pg.wait_for_url(f"**/compare?batch={BATCH}#c-methods")
    assert pg.locator("#c-methods #methods-table tbody tr").count() >= 3
    assert pg.problems == [], pg.problems
