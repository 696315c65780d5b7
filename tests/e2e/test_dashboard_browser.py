"""The dashboard in headless Chromium (Playwright, Debian's /usr/bin/chromium).

A real server (:func:`service.server.serve` in a subprocess, port 0, with a token and no
workers) serves a data directory prepared here: one finished job with images, a FLIP map
and metrics, and one queued job whose progress the test then moves. The pages must load
without console errors, show the jobs live, and show the finished job's artifacts and
images. Screenshots go to ``/tmp/matforge-dashboard-*.png``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pydantic import Field

from evaluators.metrics.tonemap import magma, tonemap
from evaluators.score.kind import summarize as score_summary
from jobapi import kinds as jobapi_kinds
from jobapi.context import JobContext
from jobapi.kinds import Kind
from jobapi.params import StrictModel
from service import kinds
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.formats.exr import exr_bytes
from storage.formats.png import write_png
from storage.jobs import JobStore

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings

pytestmark = BROWSER


class GalleryParams(StrictModel):
    """Params of the test-only kind."""

    size: int = Field(default=48, ge=8, le=256, description="image side in pixels")


def run_gallery(params: GalleryParams, ctx: JobContext) -> None:
    """An EXR render, its preview, a FLIP-style error map and a metrics table."""
    s = params.size
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    rgb = np.stack([x * 2.0, y * 1.5, (1 - x) * (1 - y)], axis=-1).astype(np.float32)
    ctx.put_bytes("image.exr", exr_bytes(rgb))
    ctx.put_bytes("preview.png", write_png(None, tonemap(rgb)))
    ctx.put_bytes("flip_blurred.png", write_png(None, magma(np.abs(x - y))))
    ctx.put_json(
        "metrics.json",
        {
            "reference": "sha256:" + "0" * 64,
            "metrics": {
                "blurred": {"flip": 0.081, "psnr": 31.2, "ssim": 0.93},
                "noisy": {"flip": 0.142, "psnr": 27.9, "ssim": 0.88},
            },
            "settings": {"ppd": 67},
        },
    )


def gallery_kind() -> Kind:
    """The test-only kind; the server process registers it too (its job page asks the kind's
    summary hook for the table)."""
    return Kind(
        name="test_gallery",
        params=GalleryParams,
        runner=run_gallery,
        description="test-only gallery kind",
        summary=score_summary,  # it writes metrics.json as score does
    )


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """A data directory with one succeeded and one queued job."""
    kinds.load_builtin()
    kind = gallery_kind()
    saved = jobapi_kinds._KINDS.get(kind.name)
    jobapi_kinds.register(kind)
    settings = data_settings(tmp_path_factory, "dashboard")
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    try:
        done, _ = submit({"kind": kind.name, "name": "gallery demo", "params": {}}, jobs, store)
        assert run_worker(settings, max_jobs=1) == 1
        assert jobs.get(done.id).state == "succeeded"
        queued, _ = submit(
            {"kind": kind.name, "name": "still waiting", "params": {"size": 16}}, jobs, store
        )
        yield {"data": settings.data_dir, "done": jobs.get(done.id), "queued": queued, "jobs": jobs}
    finally:
        jobs.close()
        if saved is None:
            jobapi_kinds._KINDS.pop(kind.name, None)
        else:
            jobapi_kinds.register(saved)


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def test01_jobs_list_live(page: Any, server: str, prepared: dict[str, Any]) -> None:
    done, queued = prepared["done"], prepared["queued"]
    page.goto(f"{server}/?token={TOKEN}")
    # the page drops the token from the address bar (replaceState: ask the page itself)
    page.wait_for_function("() => !location.href.includes('token=')")
    done_row = page.locator(f'tr[data-id="{done.id}"]')
    done_row.wait_for(timeout=10_000)
    assert done_row.locator(".badge").inner_text() == "succeeded"
    assert "gallery demo" in done_row.inner_text() and "100%" in done_row.inner_text()
    queued_row = page.locator(f'tr[data-id="{queued.id}"]')
    assert queued_row.locator(".badge").inner_text() == "queued"
    assert page.locator('[data-count="total"]').inner_text() == "2"

    # the list is live: move the queued job along and watch its row follow
    jobs: JobStore = prepared["jobs"]
    claimed = jobs.claim("test-host:1", 60.0, job_id=queued.id)
    assert claimed is not None and claimed.lease_token
    jobs.heartbeat(queued.id, claimed.lease_token, 60.0, progress=0.42, message="halfway")
    page.wait_for_function(
        f"""() => {{
            const row = document.querySelector('tr[data-id="{queued.id}"]');
            return row && row.querySelector('.badge').textContent === 'running'
                   && row.textContent.includes('42%') && row.textContent.includes('halfway');
        }}""",
        timeout=10_000,
    )
    page.select_option("#f-state", "succeeded")
    page.wait_for_function(
        f"() => !document.querySelector('tr[data-id=\"{queued.id}\"]')", timeout=10_000
    )
    # replaceState reaches Playwright's page.url asynchronously: ask the page itself.
    page.wait_for_function("() => location.href.includes('state=succeeded')")
    page.select_option("#f-state", "")
    page.locator(f'tr[data-id="{queued.id}"]').wait_for(timeout=10_000)
    page.screenshot(path=str(SHOTS / "matforge-dashboard-index.png"), full_page=True)
    jobs.cancel(queued.id)
    page.wait_for_function(
        f"""() => document.querySelector('tr[data-id="{queued.id}"] .badge')
                  .textContent === 'cancelled'""",
        timeout=10_000,
    )
    assert page.problems == [], page.problems


def test02_job_page(page: Any, server: str, prepared: dict[str, Any]) -> None:
    done = prepared["done"]
    page.goto(f"{server}/jobs/{done.id}?token={TOKEN}")
    assert page.locator("#job-state").inner_text() == "succeeded"
    assert page.locator("h1").inner_text() == "gallery demo"
    rows = page.locator("#artifacts-table tbody tr")
    names = {rows.nth(i).locator("td").first.inner_text() for i in range(rows.count())}
    assert names == {"image.exr", "preview.png", "flip_blurred.png", "metrics.json"}
    images = page.locator(".gallery img")
    assert images.count() == 3  # the EXR (through its preview), the PNG, the FLIP map
    page.wait_for_function(
        "() => [...document.querySelectorAll('.gallery img')]"
        ".every(i => i.complete && i.naturalWidth > 0)",
        timeout=10_000,
    )
    srcs = [images.nth(i).get_attribute("src") for i in range(images.count())]
    assert any(s.endswith("/preview.png") and "/api/artifacts/" in s for s in srcs)
    assert page.locator("#metrics-table tbody tr").count() == 2
    colorbar = page.locator(".colorbar")  # the FLIP maps' scale, in numbers
    assert colorbar.is_visible() and colorbar.locator(".colorbar-ticks").inner_text().split() == [
        "0",
        "0.25",
        "0.5",
        "0.75",
        "1",
    ]
    assert page.locator("#metrics-charts canvas").count() == 3
    # PSNR (higher is better) does not start at 0; FLIP (an error) does
    scale = "c => Chart.getChart(c).scales.y.min"
    assert page.locator('canvas[data-metric="psnr"]').evaluate(scale) > 0
    assert page.locator('canvas[data-metric="flip"]').evaluate(scale) == 0
    assert "numpy" in page.locator("table.packages").inner_text()
    assert '"test_gallery"' in page.locator("pre.code").first.inner_text()
    page.screenshot(path=str(SHOTS / "matforge-dashboard-job.png"), full_page=True)
    assert page.problems == [], page.problems


def test03_without_token_is_refused(page: Any, server: str) -> None:
    response = page.goto(f"{server}/")
    assert response is not None and response.status == 401
    page.problems.clear()  # the 401 itself is expected here


def test04_api_docs_offline(page: Any, server: str) -> None:
    """``/docs`` renders the OpenAPI document with the vendored Swagger UI (no CDN)."""
    page.goto(f"{server}/docs?token={TOKEN}")
    page.locator(".opblock").first.wait_for(timeout=15_000)
    assert page.locator(".opblock").count() >= 10
    page.locator("section.models").wait_for(timeout=10_000)
    models = page.locator("section.models").inner_text()
    page.screenshot(path=str(SHOTS / "matforge-docs.png"), full_page=True)
    builtin = [k for k in kinds.all_kinds().values() if not k.name.startswith("test_")]
    for kind in builtin:  # Swagger UI lists schemas by title
        assert kind.params.model_json_schema()["title"] in models, (kind.name, models)
    assert page.locator(".errors-wrapper").count() == 0
    assert page.problems == [], page.problems
