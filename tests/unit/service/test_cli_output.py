"""Pieces of the CLI's output: the ETA of a running job, tables split to fit a width,
and the notices of a resubmitted spec."""

from __future__ import annotations

import io
from typing import Any

import pytest
from rich.console import Console

from service.cli.follow import eta_of, format_eta
from service.cli.resubmit import reuse_notices
from service.cli.tables import column_chunks, fitted_tables


def test01_eta_extrapolates_the_run_time() -> None:
    doc = {"state": "running", "progress": 0.25, "timings": {"run_seconds": 30.0}}
    assert eta_of(doc) == format_eta(90.0) == "ETA 0:01:30"
    assert eta_of({**doc, "progress": 0.001}) == ""  # too early to tell
    assert eta_of({**doc, "state": "queued"}) == ""
    assert eta_of({**doc, "timings": {"run_seconds": None}}) == ""
    assert format_eta(3 * 3600 + 5) == "ETA 3:00:05"


def test02_columns_are_split_to_fit() -> None:
    assert column_chunks([10, 10, 10], first=10, total=100) == [[0, 1, 2]]
    assert column_chunks([10, 10, 10], first=10, total=31) == [[0, 1], [2]]
    assert column_chunks([50, 5], first=10, total=30) == [[0], [1]]  # too wide: alone
    headers = [f"metric_{i}" for i in range(12)]
    rows = [("candidate_a", [f"{0.1 * i:.4f}" for i in range(12)])]
    tables = fitted_tables("scores", "label", headers, rows, width=60)
    assert len(tables) > 1
    out = io.StringIO()
    console = Console(file=out, width=60)
    for t in tables:
        console.print(t)
    text = out.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 60
    assert all(h in text for h in headers)  # nothing dropped or cut
    assert text.count("candidate_a") == len(tables)


def test03_reuse_notices() -> None:
    doc = {"id": "a" * 32, "state": "succeeded", "name": "first"}
    assert reuse_notices({"name": "x"}, doc, created=True) == []
    (line,) = reuse_notices({"name": "first"}, doc, created=False)
    assert line == f"reusing job {'a' * 32} (same spec); add `force: true` to run again"
    lines = reuse_notices({"name": "second"}, doc, created=False)
    assert len(lines) == 2 and "'second' is ignored" in lines[1] and "'first'" in lines[1]
    running = reuse_notices({}, {**doc, "state": "running"}, created=False)
    assert "(same spec, running)" in running[0]


def _jobs(message: str, name: str = "a fairly long job name for a render") -> list[dict[str, Any]]:
    return [
        {
            "id": f"{i:x}" * 32,
            "kind": kind,
            "name": name,
            "state": state,
            "progress": 0.5,
            "created_at": "2026-12-03T06:00:00.000Z",
            "message": message,
            "tags": ["gold"] if i == 1 else [],
        }
        for i, (kind, state) in enumerate(
            [("generate.fabric", "running"), ("score", "succeeded"), ("report.pareto", "queued")],
            start=1,
        )
    ]


@pytest.mark.parametrize("width", [60, 80, 100, 120, 200])
def test04_ls_keeps_id_kind_state_progress_whole(width: int) -> None:
    """At any terminal width the 12-character id, the kind, the state and the progress
    are printed whole; the table fits the width; the creation time gives way to the
    message, which wraps (tests/unit/service/test_cli_tables_fit.py)."""
    from service.cli.listing import jobs_table

    docs = _jobs("rendering pass 3 of 16 " * 10)
    out = io.StringIO()
    Console(file=out, width=width).print(jobs_table(docs, width))
    lines = out.getvalue().splitlines()
    assert max(len(line) for line in lines) <= width
    text = out.getvalue()
    for d in docs:
        row = next(line for line in lines if d["id"][:12] in line)
        for cell in (d["kind"], d["state"], "50%"):
            assert cell in row, (width, cell, row)
    if width >= 200:
        assert "2026-12-03 06:00:00" in text  # the creation time fits beside the message
    if width >= 120:
        assert "a fairly long job" in text
    if width >= 200:
        assert "rendering pass 3 of 16" in text


def test05_ls_extra_columns_keep_their_width() -> None:
    from service.cli.listing import jobs_table

    docs = [
        {**d, "columns": {"params.model": "hybrid", "metric.psnr": 31.23456}} for d in _jobs("x")
    ]
    out = io.StringIO()
    cols = [("params.model", "params.model"), ("metric.psnr", "metric.psnr")]
    Console(file=out, width=100).print(jobs_table(docs, 100, cols))
    text = out.getvalue()
    assert "params.model" in text and "hybrid" in text and "31.23" in text
    assert max(len(line) for line in text.splitlines()) <= 100


def test06_piped_output_is_narrow(monkeypatch: pytest.MonkeyPatch) -> None:
    """``matforge kinds | less``: stdout is not a terminal and COLUMNS is unset, so lines
    are at most :data:`service.cli.state.PIPE_WIDTH` characters (they were 1,758)."""
    from typer.testing import CliRunner

    from service.cli.main import app
    from service.cli.state import PIPE_WIDTH

    monkeypatch.delenv("COLUMNS", raising=False)
    for args in (["kinds"], ["kinds", "generate.glint"], ["kinds", "train.brdf"]):
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        lines = res.stdout.splitlines()
        assert len(lines) > 5
        assert max(len(line) for line in lines) <= PIPE_WIDTH <= 120, args


@pytest.mark.parametrize("width", [80, 100, 120])
def test07_batch_summary_keeps_step_kind_id_state_whole(width: int) -> None:
    """``matforge batch`` piped to a file (100 columns) or in a narrow terminal: the step,
    kind, 12-character id, state and seconds of each step are printed whole (they were
    folded into 4-character pieces, "rend/er", "succe/eded"); the result line is cut
    first. The reference is the rows' own text."""
    from jobapi.results import ResultTable
    from service.cli.batch import StepResult
    from service.cli.results import result_rows, results_table

    results = [
        StepResult(
            step=step,
            kind=kind,
            job_id=f"{i:x}" * 32,
            state="succeeded",
            seconds=15.27 * i,
            table=ResultTable(
                title="t",
                label_header="Candidate",
                columns=["flip"],
                rows={f"candidate_{j}": {"flip": 0.1 * j} for j in range(8)},
            ),
        )
        for i, (step, kind) in enumerate(
            [("gold_rougher", "render"), ("fabric", "generate.fabric"), ("scores", "score")],
            start=1,
        )
    ]
    columns, rows = result_rows(results)
    out = io.StringIO()
    Console(file=out, width=width).print(results_table(columns, rows, "batch x", results))
    lines = out.getvalue().splitlines()
    assert max(len(line) for line in lines) <= width
    for r in results:
        row = next(line for line in lines if r.job_id[:12] in line)  # type: ignore[index]
        for cell in (r.step, r.kind, "succeeded", f"{r.seconds:.4g}"):
            assert cell in row, (width, cell, row)
        assert "flip:" in row  # the result shows its start, cut at the end
        if width >= 100:
            assert "flip: candidate_0" in row
