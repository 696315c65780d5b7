"""BENCHMARKS.md's summary is the output of ``benchmarks/summary.py`` over the run records
in ``benchmarks/results/``: a hand edit, a new record or an input changed since a record
was measured (its rows turn stale) makes the committed table differ, and this test fail."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[3]


def summary_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_summary", ROOT / "benchmarks/summary.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_summary"] = mod
    spec.loader.exec_module(mod)
    return mod


S = summary_module()


def test01_the_committed_summary_is_the_commands_output() -> None:
    text = (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8")
    want = S.with_summary(text, S.summary_block(S.load_records()))
    assert text == want, (
        "BENCHMARKS.md's summary is stale: run `.venv/bin/python benchmarks/summary.py --write` "
        "(an input of a run record changed, or a record was added or edited)"
    )


def test02_every_row_says_date_machine_seeds_and_status() -> None:
    block = S.summary_block(S.load_records())
    rows = [ln for ln in block.splitlines() if ln.startswith("| ") and "---" not in ln][1:]
    assert rows
    for ln in rows:
        cells = [c.strip() for c in ln.strip("|").split(" | ")]
        assert len(cells) == len(S.COLUMNS), ln
        row = dict(zip(S.COLUMNS, cells, strict=True))
        assert row["date"][:4] == "2026" and row["machine"] != "-" and row["seeds"] != "-", ln
        assert row["status"] == "current" or row["status"].startswith("**stale**"), ln


def test03_the_btf_rows_are_stale() -> None:
    """Measured on the former 8-ring directions, one seed each: stale, and the reason is
    stated (the directions' definition changed since, and the record says so)."""
    (btf,) = [r for r in S.load_records() if r["file"] == "2026-12-01-btf-eval.json"]
    why = S.status(btf)
    assert why.startswith("**stale**")
    assert "`materials/btf/directions.py::ubo2014_directions`" in why
    assert "8-ring" in why and "seed spread" in why
    assert all(r["family"] == "BTF" for r in btf["rows"])


def test04_a_changed_input_turns_a_record_stale_and_a_change_elsewhere_does_not() -> None:
    files = {
        "a.py": "X = 1\n\n\ndef f():\n    return 2\n",
        "recipe.yaml": "steps: []\n",
    }
    inputs = ["a.py::f", "recipe.yaml"]
    digests = S.input_digests(inputs, files.get)
    rec = {"inputs": {"paths": inputs, "digests": digests, "sha256": S.inputs_hash(digests)}}
    assert S.status(rec, files.get) == "current"
    other = {**files, "a.py": "X = 3\n\n\ndef f():\n    return 2\n"}  # not f: still current
    assert S.status(rec, other.get) == "current"
    changed = {**files, "a.py": "X = 1\n\n\ndef f():\n    return 3\n"}
    assert S.status(rec, changed.get) == "**stale**: inputs changed since: `a.py::f`"
    gone = {"a.py": files["a.py"]}
    assert "`recipe.yaml`" in S.status(rec, gone.get)
    assert S.status({**rec, "stale": "one seed"}, files.get) == "**stale**: one seed"
