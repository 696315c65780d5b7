"""Which way is better, read from a metric's name (what the dashboard highlights)."""

from __future__ import annotations

import pytest

from service.metric_directions import best_labels, direction


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("flip", "lower"),
        ("psnr", "higher"),
        ("ssim", "higher"),
        ("baseline.rgb.rel", "lower"),
        ("C_warp.rel", "lower"),
        ("smape", "lower"),
        ("ns_per_eval", "lower"),
        ("samples_per_s", "higher"),
        ("mpaths", "higher"),
        ("mean_r", None),
        ("queries", None),
        ("pattern", None),
    ],
)
def test01_direction(name: str, expected: str | None) -> None:
    assert direction(name) == expected


def test02_best_labels_skip_aggregates_ties_and_text() -> None:
    rows = {
        "a": {"flip": 0.2, "psnr": 30.0, "n": 5, "pattern": "x"},
        "b": {"flip": 0.1, "psnr": 28.0, "n": 5, "pattern": "y"},
        "mean": {"flip": 0.05, "psnr": 40.0, "n": 5},
    }
    assert best_labels(rows, ["flip", "psnr", "n", "pattern"]) == {"flip": "b", "psnr": "a"}
    assert best_labels({"a": {"flip": 1.0}, "b": {"flip": 1.0}}, ["flip"]) == {}
    assert best_labels({"a": {"flip": 1.0}}, ["flip"]) == {}
