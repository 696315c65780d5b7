"""Metric names (:mod:`jobapi.metric_names`): one unit per column. A BRDF-space MAE and an
image MAE are two names, old bare names stand for their space's, and a name no kind declares
is refused with the closest known ones."""

from __future__ import annotations

import pytest

from jobapi.kinds import declared_metrics
from jobapi.metric_names import (
    ALIASES,
    matches,
    one_column,
    qualified,
    resolve,
    unknown_metric,
)
from jobapi.rows import lower_is_better
from service import kinds


def test01_spaces_name_the_metrics() -> None:
    assert qualified("brdf", "mae") == "brdf.mae" and qualified("image", "mae") == "image.mae"
    assert qualified("image", "flip_mean") == "image.flip_mean"
    assert qualified("brdf", "l1") == "l1"  # not a BRDF-space metric: as it is
    with pytest.raises(ValueError, match="unknown metric space"):
        qualified("btf", "l1")
    # the direction of a qualified name is its bare name's
    assert lower_is_better("image.psnr") is False and lower_is_better("brdf.smape") is True


def test02_old_names_stand_for_their_space() -> None:
    assert resolve("smape") == ("brdf.smape",) and resolve("flip") == ("image.flip",)
    assert resolve("mae") == ("brdf.mae", "image.mae")
    assert resolve("brdf.mae") == ("brdf.mae",)
    assert matches("brdf.smape", "smape") and matches("brdf.smape", ["flip", "smape"])
    assert not matches("image.mae", "brdf.mae")
    assert matches("image.mae", "mae") and matches("brdf.mae", "mae")
    assert matches("smape", "brdf.smape")  # a kind that still writes the old name
    assert one_column("smape") == "brdf.smape" and one_column("mae") is None


def test03_unknown_names_are_refused_with_the_closest() -> None:
    kinds.load()
    known = declared_metrics()
    for name in ("brdf.smape", "image.mae", "smape", "l1", "rgb.rel", "tabulation.missing"):
        assert unknown_metric(name, known) is None, name
    why = unknown_metric("smape_mean", known, prefix="metric.")
    assert why is not None and why.startswith("unknown metric 'smape_mean'; did you mean")
    assert "'metric.brdf.smape'" in why.split("or")[0], why  # the first suggestion
    flip = unknown_metric("flipp", known)
    assert flip is not None and "'image.flip'" in flip
    assert unknown_metric("zzz", known) == (
        "unknown metric 'zzz' (each kind's metrics: docs/reference/kinds.md)"
    )
    # as a row filter mae keeps both MAEs; as one column it would mix two units
    assert unknown_metric("mae", known) is None
    col = unknown_metric("mae", known, column=True, prefix="metric.")
    assert col is not None and "'metric.brdf.mae' or 'metric.image.mae'" in col


def test04_every_old_name_is_a_declared_metric() -> None:
    """Each alias stands for names some kind declares: none points nowhere."""
    kinds.load()
    known = declared_metrics()
    for alias, names in ALIASES.items():
        for name in names:
            assert unknown_metric(name, known) is None, (alias, name)
