"""The compare view in headless Chromium (issue 14 §1): jobs picked in the job list, their
pictures side by side with linked zoom and pan and square pixels, an exposure slider for
HDR pictures, and an A/B slider between two. Screenshot: ``/tmp/matforge-compare*.png``.

The server and the browser page are those of :mod:`.test_dashboard_list_browser` (its
``test_wide`` kind writes ``image.exr`` and ``preview.png``); the data differ.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from jobapi import kinds as jobapi_kinds
from service import kinds
from service.settings import Settings
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore

from .test_dashboard_browser import CHROMIUM, SHOTS, TOKEN, page  # noqa: F401
from .test_dashboard_list_browser import server, wide_kind  # noqa: F401

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (`make setup`)"),
]


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Three finished ``test_wide`` jobs of different brightness, in one batch."""
    kinds.load_builtin()
    kind = wide_kind()
    jobapi_kinds.register(kind)
    data = tmp_path_factory.mktemp("dashboard-compare") / "data"
    (data / "scratch").mkdir(parents=True)
    settings = Settings.from_env({}).with_(data_dir=data, pool_processes=1)
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    try:
        ids = []
        for size in (8, 16, 24):
            spec = {"kind": kind.name, "name": f"size {size}", "params": {"size": size}}
            job, _ = submit({**spec, "batch": "sizes"}, jobs, store)
            ids.append(job.id)
        assert run_worker(settings, max_jobs=3) == 3
        assert all(jobs.get(i).state == "succeeded" for i in ids)
        yield {"data": data, "ids": ids, "jobs": jobs}
    finally:
        jobs.close()
        jobapi_kinds._KINDS.pop(kind.name, None)


def loaded(pg: Any, selector: str) -> None:
    pg.wait_for_function(
        f"() => {{ const imgs = [...document.querySelectorAll({selector!r})];"
        " return imgs.length > 0 && imgs.every(i => i.complete && i.naturalWidth > 0); }"
    )


def test01_pick_in_the_list_then_compare(
    page: Any,  # noqa: F811
    server: str,  # noqa: F811
    prepared: dict[str, Any],
) -> None:
    pg = page
    ids = prepared["ids"]
    pg.goto(f"{server}/?token={TOKEN}")
    pg.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length === 3")
    assert pg.locator("#compare-btn").is_disabled()
    for job_id in ids:
        pg.locator(f'tr[data-id="{job_id}"] input.pick').check()
    assert pg.locator("#compare-btn").inner_text() == "Compare selected (3)"
    pg.click("#compare-btn")
    pg.wait_for_url("**/compare?jobs=*")
    panels = pg.locator(".compare-panel")
    assert panels.count() == 3
    assert pg.locator("#c-artifact").input_value() == "image.exr"
    loaded(pg, ".viewport img")
    # square pixels, and one zoom/pan for every view
    imgs = pg.locator(".viewport img")
    assert imgs.first.evaluate("i => getComputedStyle(i).imageRendering") == "pixelated"
    pg.locator(".viewport").first.hover()
    pg.mouse.wheel(0, -300)
    pg.wait_for_function(
        "() => document.querySelector('.viewport img').style.transform.includes('scale(1.25')"
    )
    transforms = imgs.evaluate_all("is => is.map(i => i.style.transform)")
    assert len(set(transforms)) == 1 and "scale(1.25)" in transforms[0], transforms
    # exposure: HDR pictures are re-tone-mapped by the server
    pg.locator("#c-exposure").fill("2")
    pg.wait_for_function(
        "() => [...document.querySelectorAll('.viewport img')]"
        ".every(i => i.getAttribute('src').endsWith('?exposure=2'))"
    )
    loaded(pg, ".viewport img")
    assert pg.locator("#c-exposure-value").inner_text() == "2 EV"
    pg.screenshot(path=str(SHOTS / "matforge-compare.png"))
    # the preview PNGs have no exposure control
    pg.select_option("#c-artifact", "preview.png")
    loaded(pg, ".viewport img")
    assert pg.locator("#c-exposure-box").is_hidden()
    assert pg.problems == [], pg.problems


def test02_ab_slider_and_batch(
    page: Any,  # noqa: F811
    server: str,  # noqa: F811
    prepared: dict[str, Any],
) -> None:
    pg = page
    ids = prepared["ids"]
    pg.goto(f"{server}/compare?batch=sizes&token={TOKEN}")
    assert pg.locator(".compare-panel").count() == 3
    assert [t.split(" · ")[0] for t in pg.locator(".compare-panel .job-id").all_inner_texts()] == [
        i[:12] for i in ids
    ]
    pg.check('input[name="c-mode"][value="ab"]')
    pg.locator(".viewport-ab").wait_for()
    assert pg.locator("#c-a").input_value() == ids[0] and pg.locator("#c-b").input_value() == ids[1]
    loaded(pg, ".viewport-ab img")
    pg.locator("#c-split").fill("30")
    assert "30%" in pg.locator(".ab-clip").evaluate("c => c.style.clipPath")
    pg.click("#c-flip")
    assert "100%" in pg.locator(".ab-clip").evaluate("c => c.style.clipPath")
    pg.select_option("#c-b", ids[2])
    loaded(pg, ".viewport-ab img")
    assert pg.locator(".ab-labels").inner_text().count("size") == 2
    pg.screenshot(path=str(SHOTS / "matforge-compare-ab.png"))
    assert pg.problems == [], pg.problems


def test03_bad_ids_are_named(page: Any, server: str) -> None:  # noqa: F811
    # a malformed id is a 422, as /api/jobs/zzz answers (issue 21, item 12); it was a 404
    response = page.goto(f"{server}/compare?jobs=zzz&token={TOKEN}")
    assert response is not None and response.status == 422
    assert "not a job id: 'zzz'" in page.locator("body").inner_text()
    # a well-formed id of no job is still a 404 that names it
    response = page.goto(f"{server}/compare?jobs=abc0123&token={TOKEN}")
    assert response is not None and response.status == 404
    assert "no job 'abc0123'" in page.locator("body").inner_text()
    page.problems.clear()  # the 422 and 404 themselves are expected


def test04_training_curves_overlaid(
    page: Any,  # noqa: F811
    server: str,  # noqa: F811
    prepared: dict[str, Any],
) -> None:
    """Issue 14 §2: several runs' curves.json in one chart, a series at a time."""
    ids = prepared["ids"]
    page.goto(f"{server}/compare?jobs={','.join(i[:10] for i in ids)}&token={TOKEN}")
    page.wait_for_function(
        "() => { const c = Chart.getChart(document.getElementById('c-curves-chart'));"
        " return c && c.data.datasets.length === 3; }"
    )
    assert page.locator("#c-series").input_value() == "loss"
    page.select_option("#c-series", "mse.C_warp")
    title = page.locator("#c-curves-chart").evaluate(
        "c => Chart.getChart(c).options.plugins.title.text"
    )
    assert title == "mse.C_warp: 3 run(s)"
    labels = page.locator("#c-curves-chart").evaluate(
        "c => Chart.getChart(c).data.datasets.map(d => d.label)"
    )
    assert [label.split(" (")[0] for label in labels] == ["size 8", "size 16", "size 24"]
    assert page.problems == [], page.problems
