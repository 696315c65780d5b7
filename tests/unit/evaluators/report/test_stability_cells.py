"""The cells of ``report.stability``'s heat table (:func:`evaluators.report.plots.heat_cells`):
a model with one family has that family as its whole set, a ratio of 1 by construction, which
the table printed as "1.00x" in every cell of such a panel; it is shown as its error alone.
The references are the cells' own numbers."""

from __future__ import annotations

from typing import Any

from evaluators.report.plots import heat_cells, stability_png


def cell(candidate: str, family: str, mean: float, ratio: float | None) -> dict[str, Any]:
    return {"kind": "train.brdf", "candidate": candidate, "family": family, "metric": "smape",
            "mean": mean, "worst": mean, "n": 1, "whole": mean, "ratio": ratio}  # fmt: skip


def test01_a_models_one_family_shows_no_ratio() -> None:
    (only,) = heat_cells([cell("hybrid 16x2", "custom", 0.7238, 1.0)])
    assert only == (None, "0.724\n(its whole set)")


def test02_several_families_keep_their_ratios() -> None:
    cells = heat_cells([cell("hybrid", "metal", 0.1, 0.5), cell("hybrid", "blend", 0.3, 1.5),
                        cell("neural", "metal", 0.2, 1.0)])  # fmt: skip
    assert cells[0] == (0.5, "0.1\n0.50x") and cells[1] == (1.5, "0.3\n1.50x")
    assert cells[2] == (None, "0.2\n(its whole set)")  # neural: one family here
    assert not any("1.00x" in text for _, text in cells)


def test03_the_png_is_drawn() -> None:
    png = stability_png([cell("hybrid 16x2", "custom", 0.7238, 1.0)], [])
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
