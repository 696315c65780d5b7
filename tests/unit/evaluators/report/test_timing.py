"""Which model a comparison's timing pass times for each candidate
(:func:`evaluators.report.timing.pass_targets`), and the refusal of a cost that cannot be
re-timed in the pass."""

from __future__ import annotations

import pytest

from evaluators.report.kind import ReportParetoParams
from evaluators.report.timing import Target, TimingParams, pass_targets, target_of
from jobapi.errors import JobFailed
from jobapi.rows import ResultRow

JOB = "a" * 32


def row(cand: str, config: dict[str, object], ns: float | None = 10.0) -> ResultRow:
    return ResultRow(job=JOB, kind="score", metric="smape", value=0.1, candidate=cand,
                     config=config, ns_per_eval=ns)  # fmt: skip


def test01_targets_from_the_rows_config() -> None:
    trained = row("hybrid 16x2", {"model": "hybrid", "model_file": f"job:{JOB}/model.json"})
    assert target_of(trained) == Target("model", f"job:{JOB}/model.json")
    scored = row("h", {"model": f"job:{JOB}/model.json", "material": "gold"})
    assert target_of(scored) == Target("model", f"job:{JOB}/model.json", "gold")
    mine = row("mine", {"external": {"model": "sha256:" + "0" * 64, "kind": "brdf"}})
    assert target_of(mine) == Target("external", "sha256:" + "0" * 64, kind="brdf")
    rung = row("r", {"material": {"model": f"job:{JOB}/model.json", "material": "m"}})
    assert target_of(rung) == Target("model", f"job:{JOB}/model.json", "m")
    assert target_of(row("hybrid", {"model": "hybrid"})) is None  # a type, not a file


def test02_first_row_per_candidate_and_refusal() -> None:
    rows = [
        row("h", {"model_file": f"job:{JOB}/model.json"}),
        row("h", {"model_file": f"job:{'b' * 32}/model.json"}),  # another seed: same config
        row("table", {}, ns=None),  # no cost, no model: not timed, not refused
        row("untimed", {"model_file": f"job:{JOB}/model.json"}, ns=None),  # timed here
    ]
    assert pass_targets(rows, "ns_per_eval") == {
        "h": Target("model", f"job:{JOB}/model.json"),
        "untimed": Target("model", f"job:{JOB}/model.json"),
    }
    with pytest.raises(JobFailed, match="ns_per_eval of glint cannot be re-timed"):
        pass_targets([*rows, row("glint", {})], "ns_per_eval")


def test03_timing_settings() -> None:
    assert TimingParams().repeats == 5
    with pytest.raises(ValueError, match="greater than or equal to 5"):
        TimingParams(repeats=4)
    p = ReportParetoParams(runs=[f"job:{JOB}"])
    assert "timing" not in p.model_dump()  # the default keeps the old canonical form
    assert (
        ReportParetoParams(runs=[f"job:{JOB}"], timing={"repeats": 9}).model_dump()["timing"][
            "repeats"
        ]
        == 9
    )


def test04_counts_ride_along() -> None:
    # rows that carry machine-independent counts (where the row type has them) hand them
    # to the pass's cost record
    class Counted:
        candidate, config, ns_per_eval = "h", {"model_file": f"job:{JOB}/model.json"}, 1.0
        macs_per_eval, bytes_per_eval = 512, 2048

    (t,) = pass_targets([Counted()], "ns_per_eval").values()  # type: ignore[list-item]
    assert dict(t.counts) == {"macs_per_eval": 512.0, "bytes_per_eval": 2048.0}
