"""The compare view in headless Chromium (issue 14 §1): jobs picked in the job list, their
pictures side by side with linked zoom and pan and square pixels, an exposure slider for
HDR pictures, and an A/B slider between two. Screenshot: ``/tmp/matforge-compare*.png``.

The server and the browser page are those of :mod:`.test_dashboard_list_browser` (its
``test_wide`` kind writes ``image.exr`` and ``preview.png``); the data differ.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from jobapi import kinds as jobapi_kinds
from service import kinds
from service.submission import submit
from service.workers.worker import run_worker
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import JobStore

from .browser import BROWSER, SHOTS, TICK_BOXES, TOKEN, browser_server, data_settings
from .test_dashboard_list_browser import url_has, wide_kind

pytestmark = BROWSER
server = browser_server("tests.e2e.test_dashboard_list_browser:wide_kind")


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    """Three finished ``test_wide`` jobs of different brightness, in one batch; and, in the
    batch ``mixed``, a fourth one and two real ``score`` jobs of their ``image.exr`` with
    different candidate labels (``gold8``/``gold24`` and ``silver8``) and one reference."""
    kinds.load_builtin()
    kind = wide_kind()
    jobapi_kinds.register(kind)
    settings = data_settings(tmp_path_factory, "dashboard-compare")
    jobs, store = JobStore(settings.db_path), ArtifactStore(settings.store_dir)
    try:
        ids = []
        for size in (8, 16, 24):
            spec = {"kind": kind.name, "name": f"size {size}", "params": {"size": size}}
            job, _ = submit({**spec, "batch": "sizes"}, jobs, store)
            ids.append(job.id)
        assert run_worker(settings, max_jobs=3) == 3
        assert all(jobs.get(i).state == "succeeded" for i in ids)
        spec = {"kind": kind.name, "name": "size 12", "params": {"size": 12}, "batch": "mixed"}
        lone, _ = submit(spec, jobs, store)
        exr = {size: f"job:{i}/image.exr" for size, i in zip((8, 16, 24), ids, strict=True)}
        scores = []
        for name, cands in (
            ("score gold", {"gold8": 8, "gold24": 24}),
            ("score silver", {"silver8": 8}),
        ):
            params = {"reference": exr[16], "candidates": {k: exr[v] for k, v in cands.items()},
                      "metrics": ["flip", "psnr"]}  # fmt: skip
            job, _ = submit(
                {"kind": "score", "name": name, "params": params, "batch": "mixed"}, jobs, store
            )
            scores.append(job.id)
        assert run_worker(settings, max_jobs=3) == 3
        assert all(jobs.get(i).state == "succeeded" for i in [lone.id, *scores])
        yield {"data": settings.data_dir, "ids": ids, "jobs": jobs, "scores": scores,
               "lone": lone.id, "store": store}  # fmt: skip
    finally:
        jobs.close()
        jobapi_kinds._KINDS.pop(kind.name, None)


def loaded(pg: Any, selector: str) -> None:
    pg.wait_for_function(
        f"() => {{ const imgs = [...document.querySelectorAll({selector!r})];"
        " return imgs.length > 0 && imgs.every(i => i.complete && i.naturalWidth > 0); }"
    )


def test01_pick_in_the_list_then_compare(page: Any, server: str, prepared: dict[str, Any]) -> None:
    pg = page
    ids = prepared["ids"]
    pg.goto(f"{server}/?token={TOKEN}")
    pg.wait_for_function("() => document.querySelectorAll('#jobs-body tr[data-id]').length === 6")
    assert pg.locator("#compare-btn").is_disabled()
    for job_id in ids:
        pg.locator(f'tr[data-id="{job_id}"] input.pick').check()
    assert pg.locator("#compare-btn").inner_text() == "Compare selected (3)"
    pg.click("#compare-btn")
    pg.wait_for_url("**/compare?jobs=*")
    panels = pg.locator(".compare-panel")
    assert panels.count() == 3
    # the main view first: each job's lead picture (test_wide's preview.png), then by name
    assert pg.locator("#c-picture").input_value() == "main"
    assert pg.locator(".pic-role").all_inner_texts() == ["preview.png"] * 3
    pg.select_option("#c-picture", "image.exr")
    url_has(pg, "picture=image.exr")
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
    pg.select_option("#c-picture", "preview.png")
    loaded(pg, ".viewport img")
    assert pg.locator("#c-exposure-box").is_hidden()
    assert pg.problems == [], pg.problems


def test02_ab_slider_and_batch(page: Any, server: str, prepared: dict[str, Any]) -> None:
    pg = page
    ids = prepared["ids"]
    pg.goto(f"{server}/compare?batch=sizes&token={TOKEN}")
    assert pg.locator(".compare-panel").count() == 3
    assert [t.split(" · ")[0] for t in pg.locator(".compare-panel .job-id").all_inner_texts()] == [
        i[:12] for i in ids
    ]
    pg.check('input[name="c-mode"][value="ab"]')
    pg.locator(".viewport-ab").wait_for()
    tile = [f"{i[:12]}:lead:preview.png" for i in ids]
    assert (
        pg.locator("#c-a").input_value() == tile[0] and pg.locator("#c-b").input_value() == tile[1]
    )
    loaded(pg, ".viewport-ab img")
    pg.locator("#c-split").fill("30")
    assert "30%" in pg.locator(".ab-clip").evaluate("c => c.style.clipPath")
    pg.click("#c-flip")
    assert "100%" in pg.locator(".ab-clip").evaluate("c => c.style.clipPath")
    pg.select_option("#c-b", tile[2])
    loaded(pg, ".viewport-ab img")
    assert pg.locator(".ab-labels").inner_text().count("size") == 2
    pg.screenshot(path=str(SHOTS / "matforge-compare-ab.png"))
    assert pg.problems == [], pg.problems


def test03_bad_ids_are_named(page: Any, server: str) -> None:
    # a malformed id is a 422, as /api/jobs/zzz answers (issue 21, item 12); it was a 404
    response = page.goto(f"{server}/compare?jobs=zzz&token={TOKEN}")
    assert response is not None and response.status == 422
    assert "not a job id: 'zzz'" in page.locator("body").inner_text()
    # a well-formed id of no job is still a 404 that names it
    response = page.goto(f"{server}/compare?jobs=abc0123&token={TOKEN}")
    assert response is not None and response.status == 404
    assert "no job 'abc0123'" in page.locator("body").inner_text()
    page.problems.clear()  # the 422 and 404 themselves are expected


def test04_training_curves_overlaid(page: Any, server: str, prepared: dict[str, Any]) -> None:
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


# -- issue 26 §2: pictures paired by role, differences, the readout, the view in the URL ---


def _exr(prepared: dict[str, Any], job_id: str) -> np.ndarray:
    """The job's image.exr as stored (the independent reference for values in the page)."""
    record = prepared["jobs"].artifact(job_id, "image.exr")
    return read_exr(prepared["store"].open_verified(record.digest), "image.exr")


def _roles(pg: Any) -> list[str]:
    return pg.locator(".compare-panel .pic-role").all_inner_texts()


def test05_score_jobs_pair_by_role(page: Any, server: str, prepared: dict[str, Any]) -> None:
    """Two score jobs with different candidate labels: their shared reference once (both
    jobs named), every candidate, and every error map; nothing is missing."""
    pg = page
    gold, silver = prepared["scores"]
    pg.goto(f"{server}/compare?jobs={gold},{silver}&token={TOKEN}")
    assert _roles(pg) == ["reference", "candidate gold24", "candidate gold8", "candidate silver8"]
    first = pg.locator(".compare-panel").first.locator("figcaption a").all_inner_texts()
    assert first == ["score gold", "score silver"]
    loaded(pg, ".viewport img")
    pg.select_option("#c-picture", "errors")
    assert _roles(pg) == ["FLIP error of gold24", "FLIP error of gold8", "FLIP error of silver8"]
    loaded(pg, ".viewport img")
    assert pg.locator("#c-colorbar").is_visible()
    body = pg.locator("body").inner_text()
    assert pg.locator(".missing").count() == 0 and "no flip_" not in body
    pg.screenshot(path=str(SHOTS / "matforge-compare-errors.png"), full_page=True)
    assert pg.problems == [], pg.problems


def test06_one_score_jobs_candidates_side_by_side(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    pg = page
    gold = prepared["scores"][0]
    pg.goto(f"{server}/compare?jobs={gold[:8]}&token={TOKEN}")
    assert pg.locator(".compare-panel").count() == 3
    assert _roles(pg) == ["reference", "candidate gold24", "candidate gold8"]
    loaded(pg, ".viewport img")
    assert pg.locator("#c-exposure-box").is_visible()  # the inputs are EXRs
    # A/B: the reference against the first candidate
    pg.check('input[name="c-mode"][value="ab"]')
    pg.locator(".viewport-ab").wait_for()
    assert pg.locator("#c-a").input_value() == f"{gold[:12]}:reference:reference"
    assert pg.locator("#c-b").input_value() == f"{gold[:12]}:candidate:gold24"
    assert pg.problems == [], pg.problems


def test07_a_batch_shows_each_job_by_what_it_has(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """``?batch=`` of a test_wide job and two score jobs: its preview, then the score jobs'
    shared reference and three candidates; no "no image.exr" placeholders."""
    pg = page
    pg.goto(f"{server}/compare?batch=mixed&token={TOKEN}")
    assert _roles(pg) == [
        "preview.png",
        "reference",
        "candidate gold24",
        "candidate gold8",
        "candidate silver8",
    ]
    loaded(pg, ".viewport img")
    assert pg.locator(".missing").count() == 0
    assert "no image.exr" not in pg.locator("body").inner_text()
    pg.screenshot(path=str(SHOTS / "matforge-compare-batch.png"), full_page=True)
    assert pg.problems == [], pg.problems


def _hover(pg: Any, index: int, fx: float, fy: float) -> None:
    box = pg.locator(".viewport").nth(index).bounding_box()
    pg.mouse.move(box["x"] + fx * box["width"], box["y"] + fy * box["height"])


def _pixel(pg: Any) -> tuple[int, int]:
    pg.wait_for_function("() => document.getElementById('c-readout').textContent.includes('pixel')")
    text = pg.locator("#c-readout").inner_text()
    x, y = text.split("pixel (")[1].split(")")[0].split(", ")
    return int(x), int(y)


def test08_signed_difference_and_its_colour_bar(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """Reference for the values: candidate − reference, the mean over R, G, B, computed
    here from the stored EXRs with numpy."""
    pg = page
    gold = prepared["scores"][0]
    ids = prepared["ids"]
    pg.goto(f"{server}/compare?jobs={gold}&picture=diff&token={TOKEN}")
    assert _roles(pg) == ["gold24 − reference", "gold8 − reference"]
    pg.wait_for_function(
        "() => [...document.querySelectorAll('canvas.pic')]"
        ".filter(c => c.dataset.ready).length === 2"
    )
    assert pg.locator("#c-diffbar").is_visible()
    ticks = pg.locator("#c-diffbar-ticks span").all_inner_texts()
    assert (
        len(ticks) == 5
        and ticks[2] == "0"
        and ticks[0].startswith("−")
        and ticks[4].startswith("+")
    )
    assert "linear values" in pg.locator("#c-diffbar-note").inner_text()
    _hover(pg, 0, 0.7, 0.6)
    x, y = _pixel(pg)
    ref = _exr(prepared, ids[1])
    want = {
        "gold24": float((_exr(prepared, ids[2]) - ref)[y, x].mean()),
        "gold8": float((_exr(prepared, ids[0]) - ref)[y, x].mean()),
    }
    assert want["gold24"] > 0 > want["gold8"]  # brighter and darker than the reference
    got = [float(t) for t in pg.locator(".compare-panel .readout").all_inner_texts()]
    assert got == pytest.approx([want["gold24"], want["gold8"]], rel=5e-3)
    # the colours: red where brighter, blue where darker
    r, g, b = pg.locator("canvas.pic").first.evaluate(
        f"c => [...c.getContext('2d').getImageData({x}, {y}, 1, 1).data].slice(0, 3)"
    )
    assert r > b
    r, g, b = (
        pg.locator("canvas.pic")
        .nth(1)
        .evaluate(f"c => [...c.getContext('2d').getImageData({x}, {y}, 1, 1).data].slice(0, 3)")
    )
    assert b > r
    pg.screenshot(path=str(SHOTS / "matforge-compare-diff.png"), full_page=True)
    assert pg.problems == [], pg.problems


def test09_readout_gives_every_panels_value(
    page: Any, server: str, prepared: dict[str, Any]
) -> None:
    """The value under the cursor in every panel: linear RGB of the EXRs (reference: the
    stored files), and a FLIP map's error (reference: the map's own colours, inverted)."""
    pg = page
    gold = prepared["scores"][0]
    ids = prepared["ids"]
    pg.goto(f"{server}/compare?jobs={gold}&token={TOKEN}")
    loaded(pg, ".viewport img")
    _hover(pg, 1, 0.3, 0.4)
    x, y = _pixel(pg)
    pg.wait_for_function(
        "() => [...document.querySelectorAll('.compare-panel .readout')]"
        ".every(r => r.textContent.trim().length > 0)"
    )
    texts = pg.locator(".compare-panel .readout").all_inner_texts()
    for text, job_id in zip(texts, [ids[1], ids[2], ids[0]], strict=True):
        values = [float(v) for v in text.split()]
        assert values == pytest.approx(_exr(prepared, job_id)[y, x].tolist(), rel=5e-3, abs=1e-6)
    pg.select_option("#c-picture", "errors")
    loaded(pg, ".viewport img")
    _hover(pg, 0, 0.5, 0.5)
    pg.wait_for_function(
        "() => [...document.querySelectorAll('.compare-panel .readout')]"
        ".every(r => r.textContent.startsWith('FLIP '))"
    )
    for text in pg.locator(".compare-panel .readout").all_inner_texts():
        assert 0.0 <= float(text.removeprefix("FLIP ")) <= 1.0
    assert pg.problems == [], pg.problems


def _numbers(transform: str) -> list[float]:
    return [float(v) for v in re.findall(r"-?[0-9.]+", transform)]


def test10_the_view_is_in_the_address(page: Any, server: str, prepared: dict[str, Any]) -> None:
    """Picture, mode, zoom, exposure and the A/B choice round-trip through the URL."""
    pg = page
    gold, silver = prepared["scores"]
    pg.goto(f"{server}/compare?jobs={gold},{silver}&token={TOKEN}")
    loaded(pg, ".viewport img")
    pg.check('input[name="c-mode"][value="ab"]')
    pg.locator(".viewport-ab").wait_for()
    pg.select_option("#c-b", f"{silver[:12]}:candidate:silver8")
    pg.locator("#c-split").fill("30")
    pg.locator("#c-exposure").fill("1.5")
    url_has(pg, "exposure=1.5")
    pg.locator(".viewport-ab").hover()
    pg.mouse.wheel(0, -300)
    url_has(pg, "zoom=1.25")
    shared = pg.evaluate("() => location.href")
    transform = pg.locator(".viewport-ab .ab-a").evaluate("i => i.style.transform")
    for part in ("mode=ab", "split=30", f"b={silver[:12]}", "zoom=1.25"):
        assert part in shared.replace("%3A", ":").replace("%2C", ","), shared
    assert "token=" not in shared
    pg.goto(shared)  # a fresh page, as whoever got the link opens it
    pg.locator(".viewport-ab").wait_for()
    assert pg.locator('input[name="c-mode"][value="ab"]').is_checked()
    assert pg.locator("#c-picture").input_value() == "main"
    assert pg.locator("#c-b").input_value() == f"{silver[:12]}:candidate:silver8"
    assert pg.locator("#c-split").input_value() == "30"
    assert pg.locator("#c-exposure").input_value() == "1.5"
    assert pg.locator("#c-exposure-value").inner_text() == "1.5 EV"
    restored = pg.locator(".viewport-ab .ab-a").evaluate("i => i.style.transform")
    assert _numbers(restored) == pytest.approx(_numbers(transform), abs=0.006)  # 2 decimals
    assert pg.locator(".viewport-ab .ab-a").get_attribute("src").endswith("?exposure=1.5")
    # and a picture view
    pg.goto(f"{server}/compare?jobs={gold}&picture=errors")
    assert pg.locator("#c-picture").input_value() == "errors"
    assert _roles(pg) == ["FLIP error of gold24", "FLIP error of gold8"]
    # a link of before the roles (artifact=NAME) still opens its picture
    pg.goto(f"{server}/compare?jobs={gold}&artifact=flip_gold8.png")
    assert pg.locator("#c-picture").input_value() == "errors"
    url_has(pg, "picture=errors")
    assert pg.problems == [], pg.problems


@pytest.mark.parametrize("width", [1280, 800])
def test11_compare_charts_tick_labels_do_not_overlap(
    page: Any, server: str, prepared: dict[str, Any], width: int
) -> None:
    """The compare view's overlaid curves (a log axis): each tick label Chart.js draws
    clears its neighbours (they were drawn into each other)."""
    page.set_viewport_size({"width": width, "height": 900})
    ids = prepared["ids"]
    page.goto(f"{server}/compare?jobs={','.join(i[:10] for i in ids)}&token={TOKEN}")
    page.wait_for_function(
        "() => { const c = Chart.getChart(document.getElementById('c-curves-chart'));"
        " return c && c.data.datasets.length === 3; }"
    )
    axes = page.evaluate(TICK_BOXES)
    assert axes, "no chart axes on the page"
    for axis in axes:
        boxes = sorted(axis["boxes"])
        for (a, wa), (b, wb) in zip(boxes, boxes[1:], strict=False):
            assert b - a >= (wa + wb) / 2 + 2, (width, axis["chart"], axis["axis"], boxes)
    assert page.problems == [], page.problems
