"""What the dashboard's browser tests share: Debian's Chromium, the page fixture (registered
for every e2e module by ``conftest.py``) and the server fixture of a module's prepared data
directory.

A browser test module sets ``pytestmark = BROWSER``, defines a module-scoped ``prepared``
fixture (a dict with the ``data`` directory) and ``server = browser_server("module:kind")``;
its tests take ``page`` and ``server``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from service.settings import Settings

from .harness import dashboard_server

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TOKEN = "browser-s3cret"
SHOTS = Path("/tmp")

#: Per chart of a page and numeric axis: the tick labels Chart.js draws, their centres
#: and widths in the axis's font (a vertical axis: their heights, the font's size).
TICK_BOXES = """() => [...document.querySelectorAll("canvas")].flatMap((canvas) => {
  const chart = window.Chart && window.Chart.getChart(canvas);
  if (!chart) return [];
  return Object.values(chart.scales).filter((s) => s.type !== "category" && s.options.display)
    .map((s) => {
      const font = window.Chart.helpers.toFont(s.options.ticks.font);
      chart.ctx.save();
      chart.ctx.font = font.string;
      const shown = s.ticks.map((t, i) => [t, i]).filter(([t]) => t.label && t.label !== "");
      const boxes = shown.map(([t, i]) => [s.getPixelForTick(i),
        s.isHorizontal() ? chart.ctx.measureText(String(t.label)).width : font.lineHeight]);
      chart.ctx.restore();
      return {chart: canvas.getAttribute("aria-label") || canvas.id, axis: s.id, boxes};
    });
})"""

#: The marks of a browser test module: slow, and skipped without Chromium.
BROWSER = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not CHROMIUM.exists(), reason="needs Debian's chromium at /usr/bin/chromium (`make setup`)"
    ),
]


def data_settings(tmp_path_factory: pytest.TempPathFactory, name: str) -> Settings:
    """Settings (one pool process) of a new data directory, with its scratch folder, in a
    new temporary folder ``name``."""
    data = tmp_path_factory.mktemp(name) / "data"
    (data / "scratch").mkdir(parents=True)
    return Settings.from_env({}).with_(data_dir=data, pool_processes=1)


def browser_server(kind_factory: str) -> Callable[..., Iterator[str]]:
    """A module-scoped ``server`` fixture: :func:`.harness.dashboard_server` over the
    module's ``prepared["data"]``, with :data:`TOKEN`, the test kind ``kind_factory``
    (``"module:function"``) registered in the server process and no workers; yields its
    URL."""

    @pytest.fixture(scope="module")
    def server(prepared: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
        log_dir = tmp_path_factory.mktemp("server-log")
        with dashboard_server(prepared["data"], kind_factory, TOKEN, log_dir) as url:
            yield url

    return server


@pytest.fixture
def page(server: str) -> Iterator[Any]:
    """A Chromium page that records console errors, page errors, failed requests and any
    request to another origin (everything, scripts included, is served by matforge)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1280, "height": 900})
        pg = context.new_page()
        problems: list[str] = []
        pg.on(
            "console",
            lambda m: (
                problems.append(f"console {m.type}: {m.text}")
                if m.type in ("error", "warning")
                else None
            ),
        )
        pg.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        # A poll in flight when the page navigates away is aborted by the browser: not a
        # problem of the page (it showed up under load, when polls and clicks overlap).
        pg.on(
            "requestfailed",
            lambda r: (
                problems.append(f"request failed: {r.url} ({r.failure})")
                if r.failure != "net::ERR_ABORTED"
                else None
            ),
        )
        pg.on(
            "response",
            lambda r: problems.append(f"HTTP {r.status}: {r.url}") if r.status >= 400 else None,
        )
        pg.on(
            "request",
            lambda r: (
                problems.append(f"external request: {r.url}")
                if not r.url.startswith((server, "data:", "blob:"))
                else None
            ),
        )
        pg.problems = problems
        try:
            yield pg
        finally:
            context.close()
            browser.close()
