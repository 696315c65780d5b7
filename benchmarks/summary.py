"""BENCHMARKS.md's summary table, regenerated from the stored records of benchmark runs.

Each run that the summary quotes is one small JSON record in ``benchmarks/results/``
(format ``matforge.bench-run/1``): when and where it was measured (``date``, ``machine``,
``load``), the ``command`` that reproduces it, the ``seeds``, the figures of each row with
their spread, and the *inputs* that decide them: code files (or one top-level definition of
a file, ``path::NAME``) and recipes, with one SHA-256 over their contents as they were when
the figures were recorded (``inputs.sha256``, taken at the git commit ``inputs.commit``).

This script writes the summary table from those records, one row per figure, each with its
date, machine, seeds and spread, and a status: ``current`` when the inputs hash the same
today, **stale** when one of them changed since (naming it) or when the record says why it
no longer stands (``stale``: e.g. measured on a direction set that is not the preset's any
more). A stale row is a figure to re-measure, not one to quote.

    .venv/bin/python benchmarks/summary.py            # print the table
    .venv/bin/python benchmarks/summary.py --write    # put it into BENCHMARKS.md
    .venv/bin/python benchmarks/summary.py --check    # exit 1 if BENCHMARKS.md differs
    .venv/bin/python benchmarks/summary.py --hash PATH[::NAME]... [--at COMMIT]
                                                      # the inputs hash of a new record

``tests/unit/benchmarks/test_summary.py`` fails when the committed table is not this
script's output: a changed input turns its rows stale, and the table must say so.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import subprocess
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
BENCHMARKS = ROOT / "BENCHMARKS.md"
FORMAT = "matforge.bench-run/1"
#: The table sits between these markers (the docs site includes it from there).
START, END = "<!-- summary:start -->", "<!-- summary:end -->"
COLUMNS = (
    "family",
    "model / method",
    "error (spread)",
    "ns/eval",
    "ms/frame",
    "bytes",
    "training time",
    "seeds",
    "date",
    "machine",
    "command",
    "status",
)
ROW_FIELDS = ("family", "method", "error", "ns_per_eval", "ms_per_frame", "bytes", "training_time")

Reader = Callable[[str], str | None]


def working_tree(path: str) -> str | None:
    """The text of ``path`` (relative to the repository root) now, or ``None``."""
    p = ROOT / path
    return p.read_text(encoding="utf-8") if p.is_file() else None


def at_commit(commit: str) -> Reader:
    """A reader of the files as they were at ``commit`` (``git show``)."""

    def read(path: str) -> str | None:
        res = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{commit}:{path}"],
            capture_output=True,
            text=True,
            check=False,
        )
        return res.stdout if res.returncode == 0 else None

    return read


def definition(source: str, name: str) -> str | None:
    """The source of the top-level function, class or assignment ``name`` in ``source``."""
    tree = ast.parse(source)
    for node in tree.body:
        names: list[str] = []
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names = [node.name]
        elif isinstance(node, ast.Assign):
            names = [t.id for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names = [node.target.id]
        if name in names:
            return ast.get_source_segment(source, node)
    return None


def input_text(spec: str, read: Reader) -> str | None:
    """The content an input names: a file (``path``) or one definition (``path::NAME``);
    ``None`` when it does not exist."""
    path, _, name = spec.partition("::")
    text = read(path)
    if text is None or not name:
        return text
    return definition(text, name)


def input_digests(inputs: Iterable[str], read: Reader) -> dict[str, str]:
    """``{input: sha256 of its content}`` (``"missing"`` for one that does not exist)."""
    out = {}
    for spec in inputs:
        text = input_text(spec, read)
        out[spec] = "missing" if text is None else hashlib.sha256(text.encode()).hexdigest()
    return out


def inputs_hash(digests: Mapping[str, str]) -> str:
    """One SHA-256 over the inputs' names and digests, in name order."""
    joined = "\n".join(f"{k} {digests[k]}" for k in sorted(digests))
    return hashlib.sha256(joined.encode()).hexdigest()


def load_records(folder: Path = RESULTS) -> list[dict[str, Any]]:
    """The records, in the order of their ``order`` field then file name; ``ValueError``
    naming the file for one that is not a record."""
    records = []
    for path in sorted(folder.glob("*.json")):
        doc = json.loads(path.read_text(encoding="utf-8"))
        missing = [
            k
            for k in ("format", "date", "machine", "command", "seeds", "inputs", "rows")
            if k not in doc
        ]
        if doc.get("format") != FORMAT or missing:
            raise ValueError(f"{path.name}: not a {FORMAT} record (missing {missing})")
        for k in ("paths", "sha256", "digests"):
            if k not in doc["inputs"]:
                raise ValueError(f"{path.name}: inputs.{k} is missing")
        records.append({**doc, "file": path.name})
    return sorted(records, key=lambda r: (r.get("order", 1000), r["file"]))


def status(record: Mapping[str, Any], read: Reader = working_tree) -> str:
    """``current``, or why the record's figures are stale: the inputs that changed since
    they were measured, and the record's own reason."""
    now = input_digests(record["inputs"]["paths"], read)
    why = []
    if inputs_hash(now) != record["inputs"]["sha256"]:
        then = record["inputs"]["digests"]
        changed = [k for k in record["inputs"]["paths"] if now.get(k) != then.get(k)]
        why.append("inputs changed since: " + ", ".join(f"`{k}`" for k in changed))
    if record.get("stale"):
        why.append(str(record["stale"]))
    return "**stale**: " + "; ".join(why) if why else "current"


def _cell(value: Any) -> str:
    text = "-" if value in (None, "") else str(value)
    return text.replace("|", "\\|").replace("\n", " ")


def seeds_text(seeds: Sequence[int] | None) -> str:
    """``0, 1, 2 (3)``; ``1`` run for a single unseeded or fixed-seed measurement."""
    if not seeds:
        return "1 run"
    return f"{', '.join(str(s) for s in seeds)} ({len(seeds)})"


def table(records: Sequence[Mapping[str, Any]], read: Reader = working_tree) -> str:
    """The summary table (markdown) of ``records``."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + " --- |" * len(COLUMNS)]
    for rec in records:
        state = status(rec, read)
        if state != "current":
            state = f"**stale** (`{rec['file']}`)"
        for row in rec["rows"]:
            error = row.get("error")
            if row.get("spread"):
                error = f"{error} ({row['spread']})"
            seeds = row.get("seeds", rec["seeds"])
            cells = [
                row.get("family"),
                row.get("method"),
                error,
                row.get("ns_per_eval"),
                row.get("ms_per_frame"),
                row.get("bytes"),
                row.get("training_time"),
                seeds_text(seeds),
                row.get("date", rec["date"]),
                rec["machine"] + (f", load {rec['load']}" if rec.get("load") else ""),
                f"`{row.get('command', rec['command'])}`",
                state,
            ]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


def summary_block(records: Sequence[Mapping[str, Any]], read: Reader = working_tree) -> str:
    """The text between the markers: how the table is made, then the table."""
    head = (
        "Generated by `.venv/bin/python benchmarks/summary.py --write` from the run records "
        "in `benchmarks/results/` (date, machine, command, seeds, spread, and a hash of the "
        "code and recipes that decide each figure): do not edit it by hand. A row is "
        "**stale** when one of its inputs changed since it was measured, or its record says "
        "why it no longer stands; re-measure it before quoting it. Error is the family's "
        "headline metric (SMAPE over BRDF queries, FLIP of a rendered frame against a "
        "reference, L1 over the whole BTF). Commands run from the repository root as "
        "`.venv/bin/python benchmarks/<script> ...`."
    )
    notes = []
    for r in records:
        state = status(r, read)
        said = [state] if state != "current" else []
        said += [r["notes"]] if r.get("notes") else []
        if said:
            notes.append(f"- `{r['file']}`: " + " ".join(s.rstrip(".") + "." for s in said))
    foot = "\nThe runs' status and notes:\n\n" + "\n".join(notes) + "\n" if notes else ""
    return f"{START}\n{head}\n\n{table(records, read)}{foot}{END}"


def with_summary(text: str, block: str) -> str:
    """``text`` (BENCHMARKS.md) with its summary block replaced by ``block``."""
    start, end = text.find(START), text.find(END)
    if start < 0 or end < start:
        raise ValueError(f"BENCHMARKS.md has no {START} ... {END} block")
    return text[:start] + block + text[end + len(END) :]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    parser.add_argument("--check", action="store_true", help="exit 1 if BENCHMARKS.md differs")
    parser.add_argument("--hash", nargs="+", metavar="INPUT", help="the inputs hash of INPUTs")
    parser.add_argument("--at", metavar="COMMIT", help="with --hash: the files at COMMIT")
    args = parser.parse_args(argv)
    if args.hash:
        read = at_commit(args.at) if args.at else working_tree
        digests = input_digests(args.hash, read)
        doc = {"paths": list(args.hash), "commit": args.at, "digests": digests,
               "sha256": inputs_hash(digests)}  # fmt: skip
        print(json.dumps(doc, indent=2))
        return 0
    block = summary_block(load_records())
    text = BENCHMARKS.read_text(encoding="utf-8")
    new = with_summary(text, block)
    if args.check:
        if new != text:
            print(
                "BENCHMARKS.md's summary is stale: run benchmarks/summary.py --write",
                file=sys.stderr,
            )
            return 1
        return 0
    if args.write:
        BENCHMARKS.write_text(new, encoding="utf-8")
        print(f"wrote {BENCHMARKS.relative_to(ROOT)}", file=sys.stderr)
        return 0
    print(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
