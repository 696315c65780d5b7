"""service.cli.batch_local.run_steps_in_process: refs to earlier steps become their jobs'
``job:`` refs (checked against the ids the fake runner handed out), the transform applies
to every resolved spec, and the first step that does not succeed stops the run, named."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from service.cli import batch_local
from service.cli.batch import Step
from service.cli.batch_local import StepFailed, run_steps_in_process
from service.settings import Settings


@dataclass
class FakeJob:
    id: str
    state: str
    error: str | None = None


def _steps(*specs: tuple[str, dict[str, Any]]) -> list[Step]:
    return [Step(name=name, spec=spec, kind=spec["kind"]) for name, spec in specs]


@pytest.fixture
def ran(monkeypatch: pytest.MonkeyPatch) -> list[dict[str, Any]]:
    seen: list[dict[str, Any]] = []

    def fake(spec: dict[str, Any], settings: Settings) -> FakeJob:
        seen.append(spec)
        fails = spec["params"].get("fail", False)
        return FakeJob(f"id{len(seen)}", "failed" if fails else "succeeded", "boom")

    monkeypatch.setattr(batch_local, "run_in_process", fake)
    return seen


def test01_refs_resolve_to_earlier_jobs_and_transform_applies(
    ran: list[dict[str, Any]], tmp_path: Path
) -> None:
    steps = _steps(
        ("a", {"kind": "k", "params": {"n": 1}}),
        ("b", {"kind": "k", "params": {"data": "step:a", "img": "step:a/image.exr"}}),
    )

    def mark(spec: dict[str, Any]) -> dict[str, Any]:
        return {**spec, "params": {**spec["params"], "small": True}}

    jobs = run_steps_in_process(steps, Settings.from_env({}), transform=mark)
    assert [j.id for j in jobs.values()] == ["id1", "id2"]
    assert ran[1]["params"] == {"data": "job:id1", "img": "job:id1/image.exr", "small": True}
    assert steps[1].spec["params"]["data"] == "step:a"  # the batch itself is not changed


def test02_the_first_failure_stops_the_run_and_names_the_step(ran: list[dict[str, Any]]) -> None:
    steps = _steps(
        ("a", {"kind": "k", "params": {"fail": True}}),
        ("b", {"kind": "k", "params": {}}),
    )
    with pytest.raises(StepFailed, match=r"step a failed: boom"):
        run_steps_in_process(steps, Settings.from_env({}))
    assert len(ran) == 1


def test03_a_ref_to_a_step_not_run_is_refused(ran: list[dict[str, Any]]) -> None:
    with pytest.raises(KeyError, match="step:zzz"):
        run_steps_in_process(
            _steps(("b", {"kind": "k", "params": {"x": "step:zzz"}})), Settings.from_env({})
        )
    assert ran == []
