"""The docs site: it builds with ``mkdocs build --strict`` (a broken link or anchor, a
missing page or a failing generated page fails), and its committed generated pages are
current."""

from __future__ import annotations

import html
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, REPO / "scripts" / f"{name}.py")
    assert spec and spec.loader
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test01_cli_reference_is_current() -> None:
    page = (REPO / "docs/reference/cli.md").read_text(encoding="utf-8")
    assert page == _script("cli_reference").cli_markdown(), (
        "docs/reference/cli.md is stale: run `.venv/bin/python scripts/cli_reference.py --write`"
    )


@pytest.mark.timeout(300)  # mkdocs imports the application for the REST page (~15 s here)
def test02_site_builds_strict_and_offline(tmp_path: Path) -> None:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "s")],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    site = tmp_path / "s"
    rest = (site / "reference/rest/index.html").read_text(encoding="utf-8")
    assert "/api/jobs/{job_id}" in rest  # generated at build time from the OpenAPI document
    assert (site / "reference/openapi.json").stat().st_size > 0
    bench = (site / "benchmarks/index.html").read_text(encoding="utf-8")
    assert "ns/eval" in bench  # the summary was included from BENCHMARKS.md
    # offline: the theme's Google Fonts are off
    assert "fonts.googleapis.com" not in (site / "index.html").read_text(encoding="utf-8")
    # a code block scrolls sideways in a narrow column (it was clipped): every page links
    # the stylesheet that says so
    css = (site / "stylesheets/extra.css").read_text(encoding="utf-8")
    assert ".md-typeset pre > code {\n  overflow-x: auto;" in css
    for page in ("index.html", "usage/index.html", "guides/score/index.html"):
        assert "stylesheets/extra.css" in (site / page).read_text(encoding="utf-8"), page
    score = (site / "guides/score/index.html").read_text(encoding="utf-8")
    assert "SMAPE(f, g) = 2/N * sum_k |f_k - g_k| / (|f_k| + |g_k|)" in html.unescape(score)
