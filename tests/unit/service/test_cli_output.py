"""Pieces of the CLI's output: the ETA of a running job, tables split to fit a width,
and the notices of a resubmitted spec."""

from __future__ import annotations

import io

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
