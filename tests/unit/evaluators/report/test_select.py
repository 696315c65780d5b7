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


def spread_panel(points: list[tuple[str, list[float], tuple[float, float, float]]]) -> dict:  # type: ignore[type-arg]
    """Points ``(candidate, per-seed values, (cost min, median, max))``."""
    pts = [{"candidate": c, "mean": sum(v) / len(v), "n": len(v), "min": min(v), "max": max(v),
            "cost": k[1], "cost_min": k[0], "cost_max": k[2], "cost_n": 5,
            "relative": None} for c, v, k in points]  # fmt: skip
    return {"dataset": "ref", "scene": None, "metric": "smape", "cost": "ns_per_eval",
            "cost_label": "ns_per_eval", "points": pts}  # fmt: skip


def test04_choice_inside_the_timing_spread_is_not_resolved() -> None:
    # both meet the target surely; their cost ranges overlap: which is cheaper is undecided
    tied = spread_panel([("h16", [0.05, 0.06], (9.0, 10.0, 12.0)),
                         ("h32", [0.03, 0.04], (11.0, 12.0, 14.0))])  # fmt: skip
    (lad,) = ladders([tied], 0.1, lower=True)
    assert lad["chosen"] == "h16" and lad["resolved"] is False
    assert lad["tie"] == ["h16", "h32"] and "not resolved: h16 and h32" in lad["why"]
    assert lad["rungs"][0]["cost_min"] == 9.0 and lad["rungs"][0]["cost_n"] == 5
    apart = spread_panel([("h16", [0.05, 0.06], (9.0, 10.0, 10.5)),
                          ("h32", [0.03, 0.04], (11.0, 12.0, 14.0))])  # fmt: skip
    (ok,) = ladders([apart], 0.1, lower=True)
    assert ok["chosen"] == "h16" and ok["resolved"] is True and ok["tie"] == []
    assert "not resolved" not in ok["why"]


def test05_choice_inside_the_seed_spread_is_not_resolved() -> None:
    # the chosen rung's seeds straddle the target: it may not meet it
    straddle = spread_panel([("h16", [0.08, 0.12], (9.0, 10.0, 10.5)),
                             ("h32", [0.03, 0.04], (20.0, 21.0, 22.0))])  # fmt: skip
    (lad,) = ladders([straddle], 0.11, lower=True)
    assert lad["chosen"] == "h16" and lad["tie"] == ["h16"] and lad["resolved"] is False
    # a cheaper rung that fails by its mean but may meet within its seeds
    cheaper = spread_panel([("a", [0.09, 0.15], (1.0, 1.0, 1.0)),
                            ("h32", [0.03, 0.04], (20.0, 21.0, 22.0))])  # fmt: skip
    (lad2,) = ladders([cheaper], 0.1, lower=True)
    assert lad2["chosen"] == "h32" and lad2["tie"] == ["h32", "a"]
    # none meets by its mean, but one may within its seeds
    (none,) = ladders([cheaper], 0.02, lower=True)
    assert none["chosen"] is None and none["tie"] == [] and none["resolved"] is True
    (maybe,) = ladders([cheaper], 0.095, lower=True)
    assert maybe["chosen"] == "h32"


def test06_costs_from_separate_jobs_are_not_resolved() -> None:
    # a runs-mode ladder by render_seconds: each render timed itself, in its own job
    p = panel(LADDER)
    p["job_timed"] = True
    (lad,) = ladders([p], 0.05, lower=True)
    assert lad["chosen"] == "net16" and lad["resolved"] is False
    assert set(lad["tie"]) == {r[0] for r in LADDER} and "separate passes" in lad["why"]
