"""``select`` on the BRDF ladder in its scene: runs ``scripts/select_brdf.yaml`` and prints
its rungs.

Every step runs in-process as ``matforge batch`` would run it (``step:`` refs resolved; a
step whose spec already ran in ``--data-dir`` is reused, so the recipe resumes). Then one
markdown row per rung, in the ladder's order of cost: FLIP against the path-traced table,
``frame_seconds`` (frame time with the kernels compiled), ``render_seconds`` (the shard's
whole wall time) and whether it meets the target; and the chosen rung. Writes
``select.png`` of the job to ``--png``.

Run: ``.venv/bin/python benchmarks/bench_select_brdf.py [--data-dir DIR] [--png select.png]``
(about 6 minutes on 2 cores: three 20,000-step fits, then the renders).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RECIPE = Path(__file__).resolve().parent.parent / "scripts" / "select_brdf.yaml"


def main() -> None:
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process
    from service.settings import Settings
    from storage.artifacts import ArtifactStore

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=Path("select-brdf-data"))
    parser.add_argument("--png", type=Path, default=Path("select_brdf.png"))
    args = parser.parse_args()
    print(
        f"# load average {os.getloadavg()[0]:.1f} at start, {time.strftime('%Y-%m-%d %H:%M UTC')}"
    )
    settings = Settings.from_env({}).with_(data_dir=args.data_dir, pool_processes=2)

    def done(step: Any, job: Any, seconds: float) -> None:
        print(f"  {step.name}: {seconds:.0f} s; {job.message}", file=sys.stderr, flush=True)

    try:
        jobs = run_steps_in_process(load_batch(RECIPE).steps, settings, on_step=done)
    except StepFailed as exc:
        sys.exit(str(exc))
    store = ArtifactStore(settings.store_dir)
    arts = {a.name: a.digest for a in jobs["select"].artifacts}
    (ladder,) = json.loads(store.read(arts["select.json"]))["ladders"]
    print("\n| rung | FLIP | frame s (kernels compiled) | render s (whole shard) | meets |")
    print("| --- | --- | --- | --- | --- |")
    for r in ladder["rungs"]:
        meets = (
            "**chosen**" if r["candidate"] == ladder["chosen"] else ("yes" if r["meets"] else "no")
        )
        print(f"| {r['candidate']} | {r['value']:.4f} | {r['frame_seconds']:.2f} | "
              f"{r['render_seconds']:.2f} | {meets} |")  # fmt: skip
    print(f"\nchosen: {ladder['chosen']} ({ladder['why']})")
    args.png.write_bytes(store.read(arts["select.png"]))
    print(f"wrote {args.png}\n# load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
