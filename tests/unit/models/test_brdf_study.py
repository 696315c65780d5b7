"""The numbers of ``report.brdf`` (:mod:`models.brdf.study`) on hand-made runs.

References: Pareto fronts and claims worked out by hand for the values below; the spread
against ``numpy`` (mean, ``std(ddof=1)``, min, max).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from models.brdf.study import Run, claims, families, group, pareto_front, spread


def run(model: str, size: str, seed: int, smapes: list[float], ns: float | None = None,
        floats: int = 11) -> Run:  # fmt: skip
    w, d = (0, 0) if size == "-" else (int(v) for v in size.split("x"))
    fams = ["metal", "iridescent", "blend"]
    rows = tuple({"name": f"m{i}", "family": fams[i % 3], "smape": s, "mae": 0.1}
                 for i, s in enumerate(smapes))  # fmt: skip
    speed = None if ns is None else {"fused_kernel_ns": ns, "fused_ns": 2 * ns, "torch_ns": 9 * ns}
    return Run(f"{model}{size}{seed}", seed, model, w, d, 4, 7 if model == "analytic" else floats,
               rows, speed, "test")  # fmt: skip


def test01_spread_matches_numpy() -> None:
    vals = [0.12, 0.09, 0.13]
    s = spread(vals)
    assert s["smape_mean"] == pytest.approx(np.mean(vals))
    assert s["smape_std"] == pytest.approx(np.std(vals, ddof=1))
    assert (s["smape_min"], s["smape_max"], s["n"]) == (0.09, 0.13, 3)
    assert spread([0.5])["smape_std"] == 0.0
    with pytest.raises(ValueError):
        spread([])


def test02_pareto_front_by_hand() -> None:
    pts: list[dict[str, Any]] = [
        {"config": "a", "ns_per_eval": 2.0, "smape_mean": 0.20},  # cheapest: on the front
        {"config": "b", "ns_per_eval": 50.0, "smape_mean": 0.10},  # on the front
        {"config": "c", "ns_per_eval": 60.0, "smape_mean": 0.15},  # beaten by b
        {"config": "d", "ns_per_eval": 200.0, "smape_mean": 0.05},  # most accurate: front
        {"config": "e", "ns_per_eval": 200.0, "smape_mean": 0.05},  # a tie is not beaten
        {"config": "f", "ns_per_eval": None, "smape_mean": 0.01},  # untimed: left out
    ]
    assert pareto_front(pts) == ["a", "b", "d", "e"]


def test03_claims_true_false_and_missing() -> None:
    runs = [run("analytic", "-", s, [0.2, 0.2, 0.2], 2.0) for s in (0, 1)]
    runs += [run("hybrid", "16x3", s, [0.1, 0.1, v], 40.0) for s, v in ((0, 0.1), (1, 0.4))]
    runs += [run("neural", "16x3", s, [0.16, 0.16, 0.16], 30.0) for s in (0, 1)]
    runs += [run("hybrid", "32x3", 0, [0.05, 0.05, 0.05], 90.0)]
    runs += [run("neural", "64x2", 0, [0.05] * 3, 90.0, floats=12), run("hybrid", "64x2", 0,
             [0.05] * 3, 90.0)]  # fmt: skip
    out = {c["claim"]: c for c in claims(group(runs))}
    h16 = out["hybrid 16x3 mean SMAPE < analytic"]
    # hybrid 16x3: seed means 0.1 and 0.2, mean 0.15 < analytic 0.2
    assert h16["holds"] is True and h16["hybrid"] == pytest.approx(0.15)
    vs = out["hybrid 16x3 mean SMAPE <= neural 16x3 at equal per-material parameters"]
    assert vs["holds"] is True and vs["paired"]["a_better_or_equal_on"] == 1  # seed 0 only
    missing = out["hybrid 32x3 mean SMAPE <= neural 32x3 at equal per-material parameters"]
    assert missing["holds"] is None and "no neural 32x3" in missing["why"]
    unequal = out["hybrid 64x2 mean SMAPE <= neural 64x2 at equal per-material parameters"]
    assert unequal["holds"] is None and "differ: 11 vs 12" in unequal["why"]
    runs[2:4] = [run("hybrid", "16x3", s, [0.3] * 3, 40.0) for s in (0, 1)]
    out = {c["claim"]: c for c in claims(group(runs))}
    assert out["hybrid 16x3 mean SMAPE < analytic"]["holds"] is False


def test04_families_single_out_the_papers_failure_cases() -> None:
    runs = [run("hybrid", "16x3", s, [0.1, 0.5 + s, 0.3], 40.0) for s in (0, 1)]
    doc = families(group(runs))
    assert doc["families"] == ["iridescent", "blend", "metal"]
    assert set(doc["highlight"]) == {"iridescent", "blend"}
    irid = doc["configs"]["hybrid 16x3"]["iridescent"]
    assert irid["smape_mean"] == pytest.approx(1.0) and irid["smape_std"] == pytest.approx(
        np.std([0.5, 1.5], ddof=1)
    )
    assert doc["worst_family"] == {"hybrid 16x3": "iridescent"}


def test05_one_cost_per_meaning() -> None:
    """A point's cost is ``ns_per_eval``, the kernel's own time (speed.json's
    ``fused_kernel_ns``), and no other ns figure of the fused evaluator is beside it under
    another name (issue 13: ``fused_ns`` 5.26 next to ``ns_per_eval`` 4.09)."""
    configs = group([run("hybrid", "16x3", s, [0.1, 0.2, 0.3], ns=4.0 + s) for s in (0, 1, 2)])
    (point,) = [c.summary() for c in configs.values()]
    assert point["ns_per_eval"] == 5.0  # median of 4, 5, 6: the kernel times
    assert "fused_ns" not in point and point["torch_ns"] == 45.0


def test_near_maximum_flags_saturated_materials() -> None:
    """SMAPE is at most 2 (Eq. 6 with eps 0: one of the values 0). A material at 1.993 in
    both models is flagged, with each configuration's mean; 1.0 is not (values by hand)."""
    from models.brdf.study import near_maximum

    runs = [run("hybrid", "16x3", s, [0.1, 1.993, 1.0]) for s in (0, 1)]
    runs += [run("neural", "16x3", s, [0.2, 1.99, 1.5]) for s in (0, 1)]
    flagged = near_maximum(group(runs))
    assert [f["material"] for f in flagged] == ["m1"]
    assert flagged[0]["smape"] == pytest.approx({"hybrid 16x3": 1.993, "neural 16x3": 1.99})
    assert "maximum 2" in flagged[0]["warning"] and flagged[0]["family"] == "iridescent"
    assert near_maximum(group([run("hybrid", "16x3", 0, [0.1, 1.7])])) == []
