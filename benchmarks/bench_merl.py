"""Seconds per MERL table of the ``generate.merl`` kind, per family, and a whole collection.

Part 1 times the shard function of the job (:func:`generators.merl.kind.tabulate_material`:
tabulation at every bin centre plus the anisotropy probes, the ``.binary`` bytes and the
half/diff PNG) on the first materials of each family of the ``merl100`` preset, drawn with
the seed a job with ``seed`` would use, in this process. Each family's first material warms
up (Mitsuba import, kernel compilation) and is reported as ``cold s``; the row's
``median s`` is over the next ``--per-family`` materials.

Part 2 runs the ``small`` preset (12 materials) through the registry exactly as
``matforge run`` does (validation, queue, a pool of 2 spawned processes, artifact store),
in a temporary data directory, and reports the wall time and the time per table.

Run: ``.venv/bin/python benchmarks/bench_merl.py [--per-family 4] [--seed 0]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from generators.merl.collections import FAMILIES, PRESETS, draw_collection  # noqa: E402
from generators.merl.kind import MaterialTask, tabulate_material  # noqa: E402
from jobapi.context import JobContext  # noqa: E402
from materials.backend import active_variant, load_mitsuba  # noqa: E402
from service.settings import Settings  # noqa: E402
from service.submission import run_in_process  # noqa: E402


def job_rng(seed: int, stream: str) -> np.random.Generator:
    """The generator ``ctx.rng(stream)`` of a job with ``seed`` (it only reads the seed)."""
    return JobContext.rng(SimpleNamespace(seed=seed), stream)  # type: ignore[arg-type]


def time_family(family: str, per_family: int, seed: int) -> tuple[float, float, int]:
    """Cold seconds of the family's first material and the median of the next ones."""
    counts = {family: PRESETS["merl100"].counts[family]}
    drawn = draw_collection(counts, {}, lambda f: job_rng(seed, f"generate.merl/{f}"))
    times = []
    for m in drawn[: per_family + 1]:
        task = MaterialTask(m.name, m.source, 180, False, None, None)
        t0 = time.perf_counter()
        tabulate_material(task)
        times.append(time.perf_counter() - t0)
    return times[0], statistics.median(times[1:]), len(times) - 1


def time_small_preset(seed: int) -> float:
    """Wall seconds of a ``small``-preset job through the registry, 2 pool processes."""
    with tempfile.TemporaryDirectory(prefix="bench-merl-") as tmp:
        settings = Settings.from_env({}).with_(
            data_dir=Path(tmp) / "data", lease_seconds=30.0, pool_processes=2
        )
        spec = {
            "kind": "generate.merl",
            "seed": seed,
            "params": {"collection": {"preset": "small"}},
        }
        t0 = time.perf_counter()
        job = run_in_process(spec, settings)
        seconds = time.perf_counter() - t0
        if job.state != "succeeded":
            raise SystemExit(f"small preset job {job.state}: {job.error}")
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--per-family", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    load_mitsuba()
    machine = f"{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"
    print("| family | source | n | cold s | median s | variant | machine | load (1 min) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    medians = []
    for family, spec in FAMILIES.items():
        cold, median, n = time_family(family, args.per_family, args.seed)
        medians.append(median)
        print(
            f"| {family} | {spec.summary} | {n} | {cold:.3f} | {median:.3f} | "
            f"{active_variant()} | {machine} | {os.getloadavg()[0]:.1f} |",
            flush=True,
        )
    print(f"\nmedian over families: {statistics.median(medians):.3f} s per table (1 process)\n")
    n_small = sum(PRESETS["small"].counts.values())
    seconds = time_small_preset(args.seed)
    print("| job | materials | pool | wall s | s per table | machine | load (1 min) |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    print(
        f"| generate.merl preset small | {n_small} | 2 processes | {seconds:.2f} | "
        f"{seconds / n_small:.2f} | {machine} | {os.getloadavg()[0]:.1f} |"
    )
    print(
        f"\nreproduce: .venv/bin/python benchmarks/bench_merl.py --per-family {args.per_family} "
        f"--seed {args.seed}"
    )


if __name__ == "__main__":
    main()
