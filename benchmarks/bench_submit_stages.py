"""CPU per stage of one submission in process (no HTTP): validation (the params model and
the canonical hash), the refs check, the lost-results look-up and the SQLite write (dedupe,
insert, commit in WAL), and the job document the response is made from.

The web process adds HTTP parsing, routing, the trip to the thread pool and the response
to these; ``bench_submit.py`` measures the whole. ``--history N`` puts N finished jobs in
the store first (half succeeded), as on a server that has run for a while.

Run: ``.venv/bin/python benchmarks/bench_submit_stages.py [--n 1000] [--history 0]``
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench_submit import _fill_history, _spec

from service import kinds
from service.specs import validate_spec
from service.submission import check_refs, lost_results
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore


def _timed(label: str, n: int, f: Callable[[], Any]) -> Any:
    c0, w0 = time.process_time(), time.perf_counter()
    out = f()
    cpu, wall = (time.process_time() - c0) / n * 1e6, (time.perf_counter() - w0) / n * 1e6
    print(f"| {label} | {cpu:.1f} us | {wall:.1f} us |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000, help="submissions")
    ap.add_argument("--history", type=int, default=0, help="earlier jobs in the store")
    a = ap.parse_args()
    kinds.load_builtin()
    with tempfile.TemporaryDirectory(prefix="bench-stages-") as d:
        jobs = JobStore(Path(d) / "jobs.sqlite3")
        store = ArtifactStore(Path(d) / "store")
        if a.history:
            _fill_history(jobs.path, a.history)
        raws = [_spec(i) for i in range(a.n)]
        print(f"{a.n} submissions, {a.history} earlier jobs; load average {os.getloadavg()[0]:.1f}")
        print("| stage | CPU per submission | wall per submission |")
        print("| --- | --- | --- |")
        n = a.n
        specs = _timed("validate (params model, canonical hash)", n, lambda: [
            validate_spec(r, variant="llvm_ad_rgb") for r in raws])  # fmt: skip
        _timed("refs check", n, lambda: [check_refs(s, jobs, store) for s in specs])
        _timed("lost results look-up", n, lambda: [
            lost_results(s.spec_hash, jobs, store) for s in specs])  # fmt: skip
        out = _timed("SQLite write (dedupe, insert, commit) and read-back", n, lambda: [
            jobs.submit(kind=s.kind, name=s.name, seed=s.seed, spec_hash=s.spec_hash,
                        spec=s.document()) for s in specs])  # fmt: skip
        _timed("job document", n, lambda: [j.document() for j, _ in out])
    print("command: .venv/bin/python benchmarks/bench_submit_stages.py " + " ".join(sys.argv[1:]))


if __name__ == "__main__":
    sys.exit(main())
