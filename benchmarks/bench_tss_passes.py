"""Texture-space shading (Xu et al. 2025, Sec. 4.2; the Table 2 analogue) with one pass at
every resolution: ``evaluate.tss`` run twice on the same student model, with
``texture_pass: per_texel`` and ``amortised_all`` (the student's 2 x 2 amortisation at every
even R), so a row's two cells differ only in the pass.

Prints per (R, N): mean FLIP against per-frame screen-space shading, and the cost per frame
relative to screen space (Dr.Jit kernel time), for both passes, and the amortised pass's
shading-kernel time over the per-texel one's; then R's texels per pixel of the view against
the paper's setting (1200^2 per eye at 2064 x 2208 per eye: 0.32 texels per pixel).

Not modelled here, each in the paper's favour of texture-space shading: two eyes (the
paper shades a radiance texture per eye and draws two 2064 x 2208 views; here one view),
quad overdraw (the paper's screen-space pass shades 2 x 2 pixel quads on a GPU, so
triangle edges cost extra lanes; our screen-space reference evaluates each pixel once), and
the GPU's fixed costs (triangle-ID texture, dispatch, half-precision arithmetic).

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_tss_passes.py --data-dir D --model
job:<c2f train.btf id> [--resolutions 32 64 96 160] [--intervals 0 2 6] [--frames 24]
[--image 128]`` (a spec that already ran in ``D`` is reused).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: The paper's setting (Sec. 5): 1200^2 texels per eye, 2064 x 2208 pixels per eye.
PAPER_TEXELS, PAPER_PIXELS = 1200 * 1200, 2064 * 2208


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--model", required=True)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[32, 64, 96, 160])
    ap.add_argument("--intervals", type=int, nargs="+", default=[0, 2, 6])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--image", type=int, default=128)
    args = ap.parse_args()

    from service.settings import Settings
    from service.submission import run_in_process
    from storage.artifacts import ArtifactStore

    settings = Settings.from_env({}).with_(data_dir=args.data_dir, pool_processes=1)
    store = ArtifactStore(settings.store_dir)
    docs: dict[str, dict[str, Any]] = {}
    for tp in ("per_texel", "amortised_all"):
        spec = {
            "kind": "evaluate.tss",
            "seed": 3,
            "params": {
                "model": args.model,
                "resolutions": args.resolutions,
                "intervals": args.intervals,
                "frames": args.frames,
                "image": [args.image, args.image],
                "texture_pass": tp,
            },
        }
        job = run_in_process(spec, settings)
        if job.state != "succeeded":
            sys.exit(f"{tp}: {job.state}: {job.error}")

        def art(name: str, job: Any = job) -> Any:
            (digest,) = [a.digest for a in job.artifacts if a.name == name]
            return json.loads(store.read(digest))

        docs[tp] = {"metrics": art("metrics.json"), "timing": art("timing.json"), "id": job.id}
    load = docs["amortised_all"]["timing"]["environment"]["load_average"]
    print(f"jobs: per_texel {docs['per_texel']['id']}, amortised_all "
          f"{docs['amortised_all']['id']}; load {load}\n")  # fmt: skip
    print("| R | texels / pixel (paper 0.32) | N | per texel: FLIP / cost | amortised: FLIP / "
          "cost | shading kernel, amortised / per texel |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    pixels = args.image * args.image
    for r in args.resolutions:
        pt = docs["per_texel"]["timing"]["passes"]["shading"][str(r)]["kernel_s"]
        am = docs["amortised_all"]["timing"]["passes"]["shading"][str(r)]["kernel_s"]
        for n in args.intervals:
            label = f"{r}/N={n}"
            cells = []
            for tp in ("per_texel", "amortised_all"):
                (row,) = [x for x in docs[tp]["metrics"]["rows"] if x["label"] == label]
                cost = docs[tp]["timing"]["rows"][label]["relative_cost"]
                cells.append(f"{row['flip_mean']:.4f} / {cost:.2f} ({row['pass']})")
            print(f"| {r} | {r * r / pixels:.2f} | {n} | {cells[0]} | {cells[1]} | "
                  f"{am / pt:.2f} |")  # fmt: skip
    print(
        f"\nthe paper's ratio at this view: R = {(PAPER_TEXELS / PAPER_PIXELS * pixels) ** 0.5:.0f}"
    )


if __name__ == "__main__":
    main()
