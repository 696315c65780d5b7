"""The ladders of ``select`` (:func:`evaluators.report.select.ladders`): rungs by cost, the
cheapest that meets the target, for errors and for higher-is-better metrics."""

from __future__ import annotations

import pytest

from evaluators.report.select import ladders


def panel(points: list[tuple[str, float, float]], metric: str = "flip") -> dict[str, object]:
    pts = [{"candidate": c, "mean": v, "n": 1, "min": v, "max": v, "cost": k}
           for c, v, k in points]  # fmt: skip
    return {"dataset": "ref", "scene": "cloth_plane", "metric": metric,
            "cost": "render_seconds", "cost_label": "render_seconds: s", "points": pts}  # fmt: skip


LADDER = [("net16", 0.04, 0.4), ("mc1", 0.20, 0.1), ("mc_eq", 0.08, 0.4), ("gt", 0.0, 20.0)]


def test01_cheapest_meeting_an_error_target() -> None:
    (lad,) = ladders([panel(LADDER)], 0.05, lower=True)
    assert [r["candidate"] for r in lad["rungs"]] == ["mc1", "mc_eq", "net16", "gt"]
    assert [r["meets"] for r in lad["rungs"]] == [False, False, True, True]
    assert lad["chosen"] == "net16" and "the cheapest of 2" in lad["why"]
    (strict,) = ladders([panel(LADDER)], 0.25, lower=True)
    assert strict["chosen"] == "mc1"


def test02_nothing_meets_and_higher_is_better() -> None:
    (none,) = ladders([panel(LADDER[:3])], 0.01, lower=True)
    assert none["chosen"] is None and "the best is net16" in none["why"]
    psnr = [("a", 20.0, 1.0), ("b", 35.0, 2.0), ("c", 40.0, 3.0)]
    (lad,) = ladders([panel(psnr, "psnr")], 30.0, lower=False)
    assert lad["chosen"] == "b" and ">= 30" in lad["why"]


def test03_frame_seconds_leaves_out_the_compiling_first_pass() -> None:
    """Hand-made clocks: four 16-spp passes, the first 5 s (compile + paths), the others 1 s
    each: 3 s for 48 samples, so 4 s for the frame's 64. One pass: its own time."""
    from evaluators.report.select_scene import frame_seconds

    assert frame_seconds([16, 16, 16, 16], [10.0, 15.0, 16.0, 17.0, 18.0]) == pytest.approx(4.0)
    assert frame_seconds([8, 4], [0.0, 3.0, 3.5]) == pytest.approx(0.5 / 4 * 12)
    assert frame_seconds([7], [1.0, 3.5]) == pytest.approx(2.5)
    with pytest.raises(ValueError, match="2 marks for 3 passes"):
        frame_seconds([1, 1, 1], [0.0, 1.0])
