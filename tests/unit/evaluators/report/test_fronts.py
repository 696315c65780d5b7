"""The numbers of ``report.pareto`` (:mod:`evaluators.report.fronts`, ``.claims``) over
hand-made rows: points as seed means with their spread, the front by brute force, families,
and claims with a reason each."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from evaluators.report.fronts import check_claim, cost_columns, error_metrics, families, panels
from jobapi.rows import ResultRow
from models.brdf.claims import brdf_claims
from models.fabric.claims import fabric_claims

D = "job:" + "d" * 32


def brdf_row(
    job: str,
    cand: str,
    value: float,
    ns: float,
    *,
    material: str = "mean",
    family: str | None = None,
    floats: int = 11,
) -> ResultRow:
    return ResultRow(
        job=job,
        kind="train.brdf",
        metric="brdf.smape",
        value=value,
        lower_is_better=True,
        dataset=D,
        candidate=cand,
        material=material,
        family=family,
        config={"per_material_params": floats},
        ns_per_eval=ns,
        bytes_per_material=4.0 * floats,
    )


def study() -> list[ResultRow]:
    seeds = {
        "analytic": ([0.30, 0.34], 2.0),
        "hybrid 16x3": ([0.10, 0.14, 0.12], 40.0),
        "neural 16x3": ([0.28, 0.30, 0.61], 35.0),
        "hybrid 32x3": ([0.20, 0.22], 100.0),
    }
    rows, n = [], itertools.count()
    for cand, (vals, ns) in seeds.items():
        for v in vals:
            job = f"{next(n):032x}"
            rows.append(brdf_row(job, cand, v, ns + 0.1 * len(rows)))  # costs vary by run
            rows.append(brdf_row(job, cand, v - 0.05, ns, material="m1", family="metal"))
            rows.append(brdf_row(job, cand, v + 0.05, ns, material="m2", family="plastic"))
    return rows


def test01_points_are_seed_spreads_and_the_front_is_the_brute_force_one() -> None:
    rows = study()
    (panel, bytes_panel) = panels(rows, ["smape"], ["ns_per_eval", "bytes_per_material"])
    # asked by its old name, the panel is the row's (BRDF-space) metric
    assert (panel["dataset"], panel["metric"], panel["cost"]) == (D, "brdf.smape", "ns_per_eval")
    assert panel["cost_label"].startswith("ns_per_eval: ns per evaluation")
    pts = {p["candidate"]: p for p in panel["points"]}
    neural = pts["neural 16x3"]
    assert neural["n"] == 3 and neural["max"] == 0.61 and neural["min"] == 0.28
    assert neural["mean"] == pytest.approx(np.mean([0.28, 0.30, 0.61]))
    assert neural["std"] == pytest.approx(np.std([0.28, 0.30, 0.61], ddof=1))
    ns = [r.ns_per_eval for r in rows if r.candidate == "neural 16x3" and r.material == "mean"]
    assert neural["cost"] == pytest.approx(np.median(ns))
    for p in panel["points"]:  # brute force on (cost, mean)
        beaten = [
            q["candidate"]
            for q in panel["points"]
            if q is not p
            and q["cost"] <= p["cost"]
            and q["mean"] <= p["mean"]
            and (q["cost"] < p["cost"] or q["mean"] < p["mean"])
        ]
        assert p["dominated_by"] == beaten and p["front"] == (not beaten)
    assert panel["front"] == ["analytic", "hybrid 16x3"]
    assert neural["dominated_by"] == ["analytic"] and not neural["front"]  # cheaper, better
    assert pts["hybrid 32x3"]["dominated_by"] == ["hybrid 16x3"]
    assert bytes_panel["cost"] == "bytes_per_material"  # all 44 bytes: the least error wins
    assert bytes_panel["front"] == ["hybrid 16x3"]


def test02_defaults_and_families() -> None:
    rows = study()
    assert error_metrics(rows, None) == ["brdf.smape"] and error_metrics(rows, ["mae"]) == ["mae"]
    assert cost_columns(rows, None) == ["ns_per_eval", "bytes_per_material"]
    fams = {(f["candidate"], f["family"]): f for f in families(rows, ["smape"])}
    metal = fams[("neural 16x3", "metal")]
    assert metal["n"] == 3 and metal["materials"] == 1
    assert metal["mean"] == pytest.approx(np.mean([0.23, 0.25, 0.56]))
    assert panels(rows, ["flip"], ["ns_per_eval"]) == []


def test03_claims_with_reasons() -> None:
    rows = study()
    claims = {c["claim"]: c for c in brdf_claims(rows, check_claim)}
    assert claims["hybrid 16x3 mean SMAPE < analytic"]["holds"] is True
    eq = claims["hybrid 16x3 mean SMAPE <= neural 16x3 at equal per-material parameters"]
    assert eq["holds"] is True and eq["b_n"] == 3 and "neural 16x3" in eq["why"]
    assert "hybrid 32x3 mean SMAPE < analytic" in claims
    worse = check_claim(rows, {"a": "hybrid 32x3", "b": "hybrid 16x3", "metric": "smape"})
    assert worse["holds"] is False and "not <" in worse["why"]
    missing = check_claim(rows, {"a": "hybrid 16x3", "b": "tiny", "metric": "smape"})
    assert missing["holds"] is None and missing["why"] == "no smape rows of tiny"
    with pytest.raises(ValueError, match="relation"):
        check_claim(rows, {"a": "x", "b": "y", "metric": "smape", "relation": ">"})
    other = [
        r.with_(config={"per_material_params": 12}) if r.candidate == "neural 16x3" else r
        for r in rows
    ]
    (bad,) = [c for c in brdf_claims(other, check_claim) if "neural" in c["claim"]]
    assert bad["holds"] is None and "floats differ" in bad["why"]


def test04_fabric_claims_per_reference() -> None:
    def score(cand: str, ref: str, flip: float) -> ResultRow:
        return ResultRow(
            job="e" * 32,
            kind="score",
            metric="image.flip",
            value=flip,
            candidate=cand,
            dataset=ref,
            lower_is_better=True,
        )

    rows = [
        score("net16", "seen", 0.10),
        score("mc_eq", "seen", 0.12),
        score("mc1", "seen", 0.3),
        score("net16", "unseen", 0.2),
        score("mc_eq", "unseen", 0.15),
    ]
    got = {c["claim"]: c["holds"] for c in fabric_claims(rows, check_claim)}
    assert got == {
        "network (16 spp) FLIP < Monte Carlo at equal time against seen": True,
        "network (16 spp) FLIP < Monte Carlo at 1 spp against seen": True,
        "network (16 spp) FLIP < Monte Carlo at equal time against unseen": False,
    }


def test05_points_name_their_runtime_and_mixed_panels_say_so() -> None:
    """A point's runtime comes from its rows; a panel whose points come from two runtimes
    names both on its cost axis, one runtime leaves the label as it is; select's rungs carry
    the runtime too."""
    from evaluators.report.select import ladders

    rows = [
        brdf_row("a1", "hybrid 32x3", 0.10, 4.0).with_(runtime="drjit-fused"),
        brdf_row("a2", "mine", 0.08, 40.0).with_(kind="score", runtime="onnxruntime"),
        brdf_row("a3", "old", 0.3, 1.0),
    ]
    (panel,) = panels(rows, ["smape"], ["ns_per_eval"])
    by = {p["candidate"]: p for p in panel["points"]}
    assert by["hybrid 32x3"]["runtime"] == "drjit-fused"
    assert by["mine"]["runtime"] == "onnxruntime" and by["old"]["runtime"] is None
    assert panel["runtimes"] == ["drjit-fused", "onnxruntime"]
    assert panel["cost_label"].endswith("[runtimes differ: drjit-fused, onnxruntime]")
    (single,) = panels(rows[:1], ["smape"], ["ns_per_eval"])
    assert "differ" not in single["cost_label"]
    (lad,) = ladders([panel], 0.2, True)
    assert {r["candidate"]: r["runtime"] for r in lad["rungs"]} == {
        "old": None,
        "hybrid 32x3": "drjit-fused",
        "mine": "onnxruntime",
    }
    assert lad["chosen"] == "hybrid 32x3"


def test06_claims_inside_the_seed_spread_are_not_resolved() -> None:
    """Hand-built seed ranges: a claim holds or fails only where the two candidates' ranges
    of per-job means do not overlap; overlapping ranges give ``holds: None`` even where the
    means differ; one job on a side keeps the means' verdict, marked unresolvable."""

    def rows_of(values: dict[str, list[float]]) -> list[ResultRow]:
        n = itertools.count()
        return [
            brdf_row(f"{next(n):032x}", cand, v, 1.0) for cand, vs in values.items() for v in vs
        ]

    # means 0.20 and 0.22 differ, but 0.15..0.25 and 0.21..0.23 overlap
    inside = check_claim(
        rows_of({"a": [0.15, 0.20, 0.25], "b": [0.21, 0.22, 0.23]}),
        {"a": "a", "b": "b", "metric": "smape"},
    )
    assert inside["holds"] is None and inside["resolved"] is False
    assert "not resolved" in inside["why"] and inside["a_seeds"] == 3
    assert inside["a_range"] == [0.15, 0.25] and inside["a_mean"] == pytest.approx(0.20)
    # disjoint ranges: the verdict stands, both ways
    apart = rows_of({"a": [0.10, 0.12, 0.11], "b": [0.13, 0.15, 0.14]})
    ok = check_claim(apart, {"a": "a", "b": "b", "metric": "smape"})
    assert ok["holds"] is True and ok["resolved"] is True
    bad = check_claim(apart, {"a": "b", "b": "a", "metric": "smape"})
    assert bad["holds"] is False and bad["resolved"] is True
    # touching ranges (max of one = min of the other) overlap
    touch = check_claim(
        rows_of({"a": [0.10, 0.13], "b": [0.13, 0.15]}), {"a": "a", "b": "b", "metric": "smape"}
    )
    assert touch["holds"] is None
    # one seed on a side: the means decide, flagged as having no spread
    single = check_claim(
        rows_of({"a": [0.10], "b": [0.13, 0.15]}), {"a": "a", "b": "b", "metric": "smape"}
    )
    assert single["holds"] is True and single["resolved"] is None and "one seed" in single["why"]
    # several rows of one job are one repeat (their mean), not several seeds
    one_job = [brdf_row("f" * 32, "a", v, 1.0) for v in (0.1, 0.3)]
    many = one_job + rows_of({"b": [0.25, 0.26]})
    assert check_claim(many, {"a": "a", "b": "b", "metric": "smape"})["a_seeds"] == 1


def test07_points_say_whose_error_they_are() -> None:
    """A run with held-out materials is charted by its test error, labelled ``test``; a
    run without any by its training error, labelled ``train``."""
    held = [
        brdf_row("h1", "hybrid", 0.30, 10.0).with_(split="test"),
        brdf_row("h1", "hybrid", 0.05, 10.0).with_(split="train"),
    ]
    fitted = [brdf_row("a1", "analytic", 0.20, 2.0).with_(split="train")]
    (panel,) = panels(held + fitted, ["brdf.smape"], ["ns_per_eval"])
    by = {p["candidate"]: p for p in panel["points"]}
    assert (by["hybrid"]["mean"], by["hybrid"]["split"]) == (0.30, "test")
    assert (by["analytic"]["mean"], by["analytic"]["split"]) == (0.20, "train")


# -- one timing pass, and decisions inside the spread ---------------------------------------


def pass_record(costs: dict[str, tuple[float, float, float]]) -> dict[str, object]:
    """A ``matforge.timing/1`` record with ``{candidate: (min, median, max)}`` ns/eval."""
    out: dict[str, object] = {}
    for cand, (lo, mid, hi) in costs.items():
        out[cand] = {
            "ns_per_eval": mid,
            "distribution": {
                "median": mid,
                "min": lo,
                "max": hi,
                "q1": lo,
                "q3": hi,
                "iqr": hi - lo,
                "n": 5,
            },  # fmt: skip
            "relative": {
                "median": mid / 2.0,
                "min": lo / 2.0,
                "max": hi / 2.0,
                "iqr": (hi - lo) / 2.0,
                "n": 5,
            },  # fmt: skip
            "runtime": "drjit-fused",
        }
    return {"format": "matforge.timing/1", "reference": "reference", "costs": out}


def two(values_a: list[float], values_b: list[float]) -> list[ResultRow]:
    rows, n = [], itertools.count()
    for cand, vals in (("a", values_a), ("b", values_b)):
        for v in vals:
            rows.append(brdf_row(f"{next(n):032x}", cand, v, 999.0))  # training costs: ignored
    return rows


def test_pass_costs_replace_the_rows_costs() -> None:
    timing = pass_record({"a": (9.0, 10.0, 11.0), "b": (19.0, 20.0, 22.0)})
    (p,) = panels(two([0.2, 0.21], [0.1, 0.11]), ["smape"], ["ns_per_eval"], timing)
    pts = {q["candidate"]: q for q in p["points"]}
    assert pts["a"]["cost"] == 10.0 and (pts["a"]["cost_min"], pts["a"]["cost_max"]) == (9, 11)
    assert pts["b"]["relative"]["median"] == 10.0 and pts["b"]["cost_n"] == 5
    assert p["timing_pass"] is True and "one timing pass" in p["cost_label"]
    # apart on both axes: a cheaper, b more accurate -> both on the front, decided
    assert p["front"] == ["a", "b"] and p["resolved"] is True and p["ties"] == []
    assert p["not_resolved"] is None


def test_front_inside_the_spread_is_not_resolved() -> None:
    # a and b overlap in cost (9..12 against 10..13) and in error over seeds: a tie
    timing = pass_record({"a": (9.0, 10.0, 12.0), "b": (10.0, 11.0, 13.0)})
    (p,) = panels(two([0.10, 0.14], [0.09, 0.13]), ["smape"], ["ns_per_eval"], timing)
    pts = {q["candidate"]: q for q in p["points"]}
    assert p["resolved"] is False and p["ties"] == [["a", "b"]]
    assert pts["a"]["tied_with"] == ["b"] and pts["a"]["resolved"] is False
    assert "not resolved" in p["not_resolved"] and "a and b" in p["not_resolved"]
    # the same medians with one seed each and no timing spread: decided
    (flat,) = panels(two([0.12], [0.11]), ["smape"], ["ns_per_eval"],
                     pass_record({"a": (10.0, 10.0, 10.0), "b": (11.0, 11.0, 11.0)}))  # fmt: skip
    assert flat["resolved"] is True and flat["front"] == ["a", "b"]


def test_dominated_inside_the_spread_is_not_resolved() -> None:
    # b costs more and errs more by its centre, but the cost ranges overlap
    timing = pass_record({"a": (9.0, 10.0, 12.0), "b": (11.0, 12.0, 14.0)})
    (p,) = panels(two([0.10, 0.11], [0.20, 0.21]), ["smape"], ["ns_per_eval"], timing)
    pts = {q["candidate"]: q for q in p["points"]}
    assert p["front"] == ["a"] and pts["b"]["dominated_by"] == ["a"]
    # b's errors are surely worse, but not its cost: a does not surely dominate it
    assert pts["b"]["resolved"] is False and pts["b"]["tied_with"] == ["a"]
    apart = pass_record({"a": (9.0, 10.0, 10.5), "b": (11.0, 12.0, 14.0)})
    (q,) = panels(two([0.10, 0.11], [0.20, 0.21]), ["smape"], ["ns_per_eval"], apart)
    assert q["resolved"] is True


def test_candidate_missing_from_the_pass_is_not_charted() -> None:
    timing = pass_record({"a": (9.0, 10.0, 11.0)})
    (p,) = panels(two([0.2], [0.1]), ["smape"], ["ns_per_eval"], timing)
    assert [q["candidate"] for q in p["points"]] == ["a"]


def test_job_timed_costs_are_charted_not_ranked() -> None:
    rows = [
        ResultRow(
            job=f"{i:032x}",
            kind="score",
            metric="flip",
            value=v,
            lower_is_better=True,
            dataset=D,
            candidate=c,
            render_seconds=s,
        )  # fmt: skip
        for i, (c, v, s) in enumerate((("mc1", 0.2, 1.0), ("net", 0.05, 3.0)))
    ]
    (p,) = panels(rows, ["flip"], ["render_seconds"])
    assert p["resolved"] is False and "separate passes" in p["not_resolved"]
    assert "not ranked" in p["cost_label"]
    (spp,) = panels([r.__class__(**{**r.__dict__, "render_seconds": None, "spp": 1 + i})
                     for i, r in enumerate(rows)], ["flip"], ["spp"])  # fmt: skip
    assert spp["resolved"] is True and spp["not_resolved"] is None


def test_pass_times_a_candidate_its_job_did_not() -> None:
    rows = [r.__class__(**{**r.__dict__, "ns_per_eval": None}) for r in two([0.2], [0.1])]
    (p,) = panels(rows, ["smape"], ["ns_per_eval"],
                  pass_record({"a": (9.0, 10.0, 11.0), "b": (19.0, 20.0, 22.0)}))  # fmt: skip
    assert {q["candidate"]: q["cost"] for q in p["points"]} == {"a": 10.0, "b": 20.0}
