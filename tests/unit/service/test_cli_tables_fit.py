"""The CLI's tables at 80, 100 and 200 columns (``COLUMNS``, as a terminal sets it) and
piped (no ``COLUMNS``: :data:`service.cli.state.PIPE_WIDTH`): every line fits, no header or
cell is cut into pieces, no column is squeezed to nothing.

The pivot's rows are shaped as the demo batch's are (renders' image statistics, a score's
candidates, datasets' own statistics, a MERL collection's table quality, a trained hybrid's
per-material scores and costs): 33 columns, which at 100 columns gave 33 zero-width
columns and at 250 headers chopped into pieces of 2-4 letters, the MERL table-quality
columns among the methods'. The reference is the rows' own text: each header and each
number appears whole on one line.
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from service.cli.results_command import show_pivot

WIDTHS = [80, 100, 200, None]  # None: piped


def _row(step: str, kind: str, metric: str, value: float, **kw: Any) -> dict[str, Any]:
    return {"job": (step * 32)[:32], "step": step, "kind": kind, "metric": metric,
            "value": value, "lower_is_better": kw.pop("lib", None), **kw}  # fmt: skip


def demo_rows() -> list[dict[str, Any]]:
    rows = []
    # (the demo's render step "plastic" is also a score candidate: one method of the pivot
    # then, whose renders' and scores' columns are one table; named apart here)
    for step in ("gold", "gold_16spp", "gold_rougher", "orange", "glint_render"):
        for metric, value in (("image.mean", 0.31), ("image.max", 4.2), ("image.nan_pixels", 0)):
            rows.append(_row(step, "render", metric, value, render_seconds=2.5, spp=256))
    for cand, flip in (("noisy_16spp", 0.05), ("rougher", 0.08), ("plastic", 0.31)):
        for metric, value, lib in (("flip", flip, True), ("psnr", 30 - 40 * flip, False),
                                   ("ssim", 1 - flip, False), ("image.smape", flip / 2, True),
                                   ("image.mae", flip / 10, True)):  # fmt: skip
            rows.append(_row("scores", "score", metric, value, candidate=cand, lib=lib))
    for metric in ("fabric.queries", "fabric.materials", "fabric.rel_stderr_median"):
        rows.append(_row("fabric", "generate.fabric", metric, 1280.0))
    for metric in ("glint.ndf_integral", "glint.slope_rms", "glint.texels"):
        rows.append(_row("glint", "generate.glint", metric, 1.0))
    for metric in ("btf.slices", "btf.texels", "btf.mean_reflectance"):
        rows.append(_row("btf", "generate.btf", metric, 0.2))
    for metric in ("tabulation.missing_bins", "tabulation.reciprocity_error",
                   "tabulation.energy_max", "tabulation.negative_bins"):  # fmt: skip
        rows.append(_row("tables", "generate.merl", metric, 0.0, lib=True))
    for mat in ("gold", "film", "plastic"):
        for metric in ("brdf.smape", "brdf.smape_floor", "brdf.mae", "brdf.smape_analytic",
                       "brdf.smape_floor_analytic", "brdf.mae_analytic"):  # fmt: skip
            rows.append(_row("hybrid", "train.brdf", metric, 0.12, material=mat, lib=True,
                             train_seconds=40.0, bytes_per_material=44.0, ns_per_eval=61.0))  # fmt: skip
    return rows


def _printed(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> tuple[str, int]:
    from service.cli.state import PIPE_WIDTH

    if width is None:
        monkeypatch.delenv("COLUMNS", raising=False)
    else:
        monkeypatch.setenv("COLUMNS", str(width))
    show_pivot(demo_rows(), "candidate", None, False)
    return capsys.readouterr().out, width or PIPE_WIDTH


@pytest.mark.parametrize("width", WIDTHS)
def test01_pivot_fits_with_whole_headers(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> None:
    text, limit = _printed(monkeypatch, capsys, width)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= limit, (width, max(map(len, lines)))
    metrics = {r["metric"] for r in demo_rows()}
    for name in metrics | {"train_seconds", "ns_per_eval", "bytes_per_material"}:
        assert re.search(rf"(^|[\s│┃]){re.escape(name)}([\s│┃]|$)", text, re.M), (width, name)
    for method in ("gold_16spp", "noisy_16spp", "glint_render", "tables", "hybrid"):
        assert method in text, (width, method)
    assert "0.12 ± 0" in text  # a hybrid's mean and spread, whole
    # no column squeezed to nothing: no empty cell between two borders
    assert not re.search(r"[│┃][│┃]", text), width


@pytest.mark.parametrize("width", WIDTHS)
def test02_table_quality_is_not_among_the_methods_metrics(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], width: int | None
) -> None:
    """The MERL collection's table quality, the datasets' statistics and the methods'
    scores are separate tables: no line holds a table-quality and a method's column."""
    text, _ = _printed(monkeypatch, capsys, width)
    tables = re.split(r"\n(?=\s*\d+ methods by)", text)
    quality = [t for t in tables if "tabulation.missing_bins" in t]
    assert quality and all("brdf.smape" not in t and "flip" not in t for t in quality), text
    scores = [t for t in tables if "noisy_16spp" in t]
    assert scores and all("tabulation" not in t and "image.mean" not in t for t in scores)
