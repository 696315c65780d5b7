"""Issue 26 §1 and §2: the lead picture of every kind, in headless Chromium. For every kind
with smoke params that writes pictures, its smoke job's page shows first the picture the
dashboard ranks first (:func:`service.routes.dashboard.picture_views`: the kind's declared
lead, at full size, or else its first picture), loaded; and the compare view of that job
shows its main pictures (its lead, or a score's reference and candidates) with no
placeholder. The kinds come from the registry, so a new one is tested too. Screenshots:
``/tmp/matforge-lead-<kind>.png``.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterator
from typing import Any

import pytest

from service import kinds
from service.compare_pictures import job_pictures
from service.routes.dashboard import picture_views
from storage.jobs import Job, JobStore
from tests.unit.service.test_dashboard_pictures import NO_LEAD

from .browser import BROWSER, SHOTS, TOKEN, browser_server, data_settings
from .test_dashboard_charts_browser import Runs

pytestmark = BROWSER

PICTURES = ("*.png", "*.exr")
#: The kinds with smoke params whose artifacts include a picture.
KINDS = sorted(
    k.name
    for k in kinds.all_kinds().values()
    if k.smoke and any(fnmatch.fnmatch(a, p) for a in k.artifacts for p in PICTURES)
)


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """The smoke job of every kind in :data:`KINDS` (inputs first)."""
    kinds.load_builtin()
    runs = Runs(data_settings(tmp_path_factory, "dashboard-lead"))
    done = {name: runs.job(name) for name in KINDS}
    failed = {n: j.error for n, j in done.items() if j.state != "succeeded"}
    assert not failed, failed
    jobs = JobStore(runs.settings.db_path)
    try:
        yield {
            "data": runs.settings.data_dir,
            "jobs": {n: jobs.get(j.id) for n, j in done.items()},
            "db": jobs,
        }
    finally:
        jobs.close()


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def test_the_picture_kinds_are_all_here() -> None:
    assert {"render", "score", "generate.fabric", "generate.glint", "generate.btf"} <= set(KINDS)


def _loaded(pg: Any, selector: str) -> None:
    pg.wait_for_function(
        "s => { const imgs = [...document.querySelectorAll(s)];"
        " return imgs.length > 0 && imgs.every(i => i.complete && i.naturalWidth > 0); }",
        arg=selector,
    )


@pytest.mark.parametrize("kind", KINDS)
def test_lead_picture_first_on_the_job_page_and_in_compare(
    page: Any, server: str, prepared: dict[str, Any], kind: str
) -> None:
    check_lead(page, server, prepared["jobs"][kind], prepared["db"])


def check_lead(pg: Any, server: str, job: Job, db: JobStore) -> None:
    """The job page shows ``job``'s lead picture first, at full size, and the compare view
    of ``job`` its main pictures, none missing (the assertions of the test above)."""
    kind = job.kind
    views = [v for v in picture_views(job.artifacts, kind) if v["group"] != "flip"]
    pg.goto(f"{server}/jobs/{job.id}?token={TOKEN}")
    if views:
        first = views[0]
        shown = pg.locator("section:has(> h2:text-is('Images')) figure img").first
        shown.scroll_into_view_if_needed()
        assert shown.get_attribute("alt") == first["name"], (kind, first["name"])
        pg.wait_for_function("i => i.complete && i.naturalWidth > 0", arg=shown.element_handle())
        # every picture kind but the reasoned exceptions declares its lead (unit test
        # test01c): shown first, above the gallery, at its own size (a whole multiple of it
        # when small; the page's width caps it)
        assert first["group"] == ("image" if kind in NO_LEAD else "lead"), (kind, first)
        if first["group"] == "lead":
            img = pg.locator(".lead figure img").first
            assert img.get_attribute("alt") == first["name"]
            lead = pg.locator(".lead").first.bounding_box()
            section = pg.locator("section:has(> h2:text-is('Images'))").bounding_box()
            assert lead["width"] >= 0.9 * section["width"], (lead, section)
            pg.wait_for_function("i => i.style.width !== ''", arg=img.element_handle())
            shown_w, natural_w, room = img.evaluate(
                "i => [i.clientWidth, i.naturalWidth,"
                " i.closest('.lead').clientWidth - 2 * 9.6]"  # the figure's padding
            )
            # a lead narrower than 320 px is enlarged by a whole factor (square pixels)
            want = natural_w * max(1, math.ceil(320 / natural_w))
            assert abs(shown_w - min(want, room)) <= 2, (kind, shown_w, natural_w, room)
            if want > natural_w:
                assert img.evaluate("i => getComputedStyle(i).imageRendering") == "pixelated"
    pg.screenshot(path=str(SHOTS / f"matforge-lead-{kind.replace('.', '-')}.png"), full_page=True)
    # the compare view's main pictures: the lead (or a score's inputs), none missing
    main = job_pictures(job, db)["main"]
    pg.goto(f"{server}/compare?jobs={job.id}&token={TOKEN}")
    assert pg.locator(".compare-panel").count() == len(main) >= 1, (kind, main)
    _loaded(pg, ".viewport img")
    assert pg.locator(".missing").count() == 0
    if views and kind != "score":
        assert pg.locator(".pic-role").first.inner_text() == views[0]["name"]
    assert pg.problems == [], pg.problems
