"""Glint evaluation (Xing et al. 2024, Sec. 7): quality, time and memory against Yan et al.

Runs ``scripts/glint_eval.yaml`` step by step in-process (each step through
:func:`service.submission.run_in_process`, ``step:`` refs resolved as ``matforge batch``
does) and prints, per example type: HDR-FLIP, PSNR and SSIM of the tiny-example render
against the 256-spp reference (from the score steps), the time per sample per pixel of
each (the render kind's own timing of its passes, kernel compilation included, divided by
spp: "ms per frame" of one sample per pixel), the speed-up, and the memory of each (NDF
maps plus lobes from ``stats.json``; the reference's lobes of the exported map). Writes all
of it as JSON to ``--out``.

With the brushed-metal glint ladder's steps run (issue 13: smooth GGX, tiny examples of
8 / 16 / 32, Yan at 64 spp, each against the 256-spp reference), it also prints the ladder:
FLIP, PSNR and SSIM, render seconds and bytes per rung from the score's result rows, the
Pareto fronts of ``report.pareto`` and the rung ``select`` chose.

With the close-up's steps run (``glint_closeup``: about 2.5 example texels per pixel), it
prints their table: FLIP, PSNR and SSIM of the tiled tiny model, the smooth GGX and Yan at
64 spp against the tiled Yan reference, and of the stochastic tiny model against Yan of the
stochastic surface; render and setup seconds (setup: the step's wall time outside its
passes, which for Yan is its precompute: the export and its lobes); memory; the tiny
model's precompute (its ``generate.glint`` step); and the glint figures: the high-pass
correlation (:mod:`tests.helpers.glint_highpass`) of the tiny model between two seeds, of the
smooth GGX between two seeds (the control: speckle only), and of the tiny model with the
lights moved, with that change over the seed-to-seed difference.

Run: ``.venv/bin/python benchmarks/bench_glint_eval.py [--data-dir DIR] [--out glint_eval.json]``
(about 25 minutes on 2 cores: the references dominate), or only the ladder (and the steps it
needs) with ``--only brushed_metal`` (about 4 minutes quiet, 20 at load average 10), or only
the close-up with ``--only closeup``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RECIPE = Path(__file__).resolve().parent.parent / "scripts" / "glint_eval.yaml"
#: Paper's Table 3 (Deer statue / Bent quad rows) for the same example sizes, for reference.
PAPER = {
    "scratches": "32x32 vs 4k: 5.1-9.8x, 85.25 MB vs 3307.5 MB",
    "isotropic_noise": "16x16 vs 4k: 5.9-9.8x, 5.32 MB vs 3307.5 MB",
    "anisotropic_noise": "16x16 vs 4k: 5.1-7.6x, 5.32 MB vs 3307.5 MB",
    "brushed_metal": "32x32 vs 4k: 5.8-9.8x, 21.31 MB vs 3307.5 MB",
    "leather": "16x16 vs 4k: 6.6x, 5.32 MB vs 3307.5 MB",
    "structured": "8x8 vs 6k: 6.1-9.8x, 1.31 MB vs 7441.9 MB",
}
LOBE_BYTES = 32


def run_recipe(data_dir: Path, only: str | None = None) -> dict[str, Any]:
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process
    from service.settings import Settings

    settings = Settings.from_env({}).with_(data_dir=data_dir, pool_processes=1)
    steps = [s for s in load_batch(RECIPE).steps if only is None or s.name.startswith(only)]

    walls: dict[str, float] = {}

    def done(step: Any, job: Any, seconds: float) -> None:
        walls[step.name] = seconds
        print(f"  {step.name}: {seconds:.0f} s", file=sys.stderr, flush=True)

    try:
        jobs = run_steps_in_process(steps, settings, on_step=done)
    except StepFailed as exc:
        sys.exit(str(exc))
    return {"settings": settings, "jobs": jobs, "walls": walls}


def _read(settings: Any, job: Any, name: str) -> Any:
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))


def _passes(job: Any) -> tuple[int, float]:
    """``(spp, seconds)`` of a render's passes, from its message."""
    m = re.search(r"at (\d+) spp in ([0-9.]+) s", job.message or "")
    if m is None:
        raise ValueError(f"no timing in {job.message!r}")
    return int(m.group(1)), float(m.group(2))


def _seconds(job: Any) -> float:
    spp, seconds = _passes(job)
    return seconds / spp


def _setup(walls: dict[str, float], name: str, job: Any) -> float:
    """A render step's seconds outside its passes: loading the data, building the layer
    (for Yan: the export and its lobes, the precompute) and the scene."""
    return walls[name] - _passes(job)[1]


def _image(settings: Any, job: Any) -> Any:
    from storage.artifacts import ArtifactStore
    from storage.formats.exr import read_exr

    (digest,) = [a.digest for a in job.artifacts if a.name == "image.exr"]
    return read_exr(ArtifactStore(settings.store_dir).open_verified(digest), "image.exr")


#: The close-up's candidates: (score step, candidate) -> render step.
CLOSEUP = {
    ("closeup_score", "smooth_ggx"): "closeup_smooth",
    ("closeup_score", "tiny"): "closeup_tiny",
    ("closeup_score", "yan"): "closeup_yan64",
    ("closeup_stochastic_score", "tiny_stochastic"): "closeup_stochastic",
    ("closeup_stochastic_score", "yan_os1"): "closeup_stochastic_yan_os1",
    ("closeup_stochastic_score", "yan16"): "closeup_stochastic_yan16",
}


def print_closeup(settings: Any, jobs: dict[str, Any], walls: dict[str, float]) -> dict[str, Any]:
    """The close-up's table (FLIP, PSNR, SSIM against Yan of the same surface, time, memory),
    the precompute of each method and the glint figures (high-pass correlations)."""
    from service.results import select_rows
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore
    from tests.helpers.glint_highpass import HIGHPASS_SIGMA, highpass_correlation

    rows = select_rows(
        JobStore(settings.db_path),
        ArtifactStore(settings.store_dir),
        job_ids=[jobs["closeup_score"].id, jobs["closeup_stochastic_score"].id],
    )
    nbytes = {str(r.candidate): r.bytes_per_material for r in rows}
    table = []
    for (score, cand), step in CLOSEUP.items():
        m = _read(settings, jobs[score], "metrics.json")["metrics"][cand]
        spp, secs = _passes(jobs[step])
        ref = "closeup_yan" if score == "closeup_score" else "closeup_stochastic_yan"
        table.append(
            {
                "method": cand, "reference": ref, "flip": m["flip"], "psnr": m["psnr"],
                "ssim": m["ssim"], "spp": spp, "render_s": secs, "ms_per_spp": 1e3 * secs / spp,
                "setup_s": _setup(walls, step, jobs[step]), "bytes": nbytes.get(cand),
            }
        )  # fmt: skip
    print(
        "\nclose-up (glint_closeup, 96x72, scratches 32x32; 2048 texels per uv, the "
        "stochastic pair 1024)"
    )
    print(
        "| method | reference | FLIP | PSNR dB | SSIM | spp | render s | ms/spp | setup s | MiB |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in table:
        mib = "-" if r["bytes"] is None else f"{r['bytes'] / 2**20:.3f}"
        print(
            f"| {r['method']} | {r['reference']} | {r['flip']:.3f} | {r['psnr']:.1f} | "
            f"{r['ssim']:.3f} | {r['spp']} | {r['render_s']:.1f} | {r['ms_per_spp']:.1f} | "
            f"{r['setup_s']:.1f} | {mib} |"
        )
    pre = {
        "tiny (generate.glint: example, lobes, NDF maps)": walls["closeup_scratches"],
        "Yan, tiled (export, lobes; setup of closeup_yan)": _setup(
            walls, "closeup_yan", jobs["closeup_yan"]
        ),
        "Yan, stochastic, oversample 2 (export, lobes; setup of closeup_stochastic_yan)": _setup(
            walls, "closeup_stochastic_yan", jobs["closeup_stochastic_yan"]
        ),
    }
    for k, v in pre.items():
        print(f"precompute: {k}: {v:.1f} s")
    figures: dict[str, float] = {}
    if "closeup_tiny_moved" in jobs:
        img = {k: _image(settings, jobs[k]).astype("float64") for k in (
            "closeup_tiny", "closeup_tiny_seed2", "closeup_smooth", "closeup_smooth_seed2",
            "closeup_tiny_moved")}  # fmt: skip
        a, b, moved = img["closeup_tiny"], img["closeup_tiny_seed2"], img["closeup_tiny_moved"]
        figures = {
            "tiny_seed1_vs_seed2": highpass_correlation(a, b),
            "smooth_seed1_vs_seed2": highpass_correlation(
                img["closeup_smooth"], img["closeup_smooth_seed2"]
            ),
            "tiny_seed1_vs_lights_moved": highpass_correlation(a, moved),
            "lights_moved_change_over_seed_noise": float(abs(a - moved).mean() / abs(a - b).mean()),
        }
        print(f"glints are glints (high-pass: log luminance minus a {HIGHPASS_SIGMA}-px blur):")
        for k, v in figures.items():
            print(f"  {k}: {v:.3f}")
    return {"rows": table, "precompute_s": pre, "glint_figures": figures}


def print_ladder(settings: Any, jobs: dict[str, Any]) -> dict[str, Any]:
    """The glint ladder's table (from the score's result rows), fronts and choice."""
    from service.results import select_rows
    from storage.artifacts import ArtifactStore
    from storage.jobs import JobStore

    rows = select_rows(
        JobStore(settings.db_path),
        ArtifactStore(settings.store_dir),
        job_ids=[jobs["brushed_metal_ladder"].id],
    )
    pareto = _read(settings, jobs["brushed_metal_pareto"], "pareto.json")
    select = _read(settings, jobs["brushed_metal_select"], "select.json")
    (lad,) = select["ladders"]
    fronts = {p["cost"]: set(p["front"]) for p in pareto["panels"]}
    table: dict[str, dict[str, Any]] = {}
    for r in rows:
        t = table.setdefault(
            str(r.candidate),
            {"bytes": r.bytes_per_material, "seconds": r.render_seconds, "spp": r.spp},
        )
        t[r.metric.removeprefix("image.")] = r.value  # image.flip: the column "flip"
    order = [x["candidate"] for x in lad["rungs"]]
    print(f"\nglint ladder, brushed metal; select: {select['metric']} <= {select['target']}")
    print("| rung | FLIP | PSNR dB | SSIM | render s | bytes | meets | front (s) | front (bytes) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    meets = {x["candidate"]: x["meets"] for x in lad["rungs"]}
    for c in order:
        t = table[c]
        print(
            f"| {c}{' (chosen)' if c == lad['chosen'] else ''} | {t['flip']:.3f} | "
            f"{t['psnr']:.1f} | {t['ssim']:.3f} | {t['seconds']:.1f} | {t['bytes']:,.0f} | "
            f"{'yes' if meets[c] else 'no'} | "
            f"{'yes' if c in fronts.get('render_seconds', ()) else 'no'} | "
            f"{'yes' if c in fronts.get('bytes_per_material', ()) else 'no'} |"
        )
    print(f"select: {lad['why']}")
    for c in pareto["claims"]:
        print(f"claim: {c['claim']}: {c['holds']} ({c['why']})")
    return {"rungs": table, "order": order, "select": lad, "claims": pareto["claims"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("glint_eval.json"))
    parser.add_argument(
        "--only", default=None, help="run only the steps whose names start with this"
    )
    args = parser.parse_args()
    data = args.data_dir or Path(tempfile.mkdtemp(prefix="glint_eval-"))
    ran = run_recipe(data, args.only)
    settings, jobs, walls = ran["settings"], ran["jobs"], ran["walls"]
    rows = []
    for name in PAPER:
        if f"{name}_score" not in jobs:
            continue
        metrics = _read(settings, jobs[f"{name}_score"], "metrics.json")["metrics"]["tiny"]
        stats = _read(settings, jobs[name], "stats.json")
        spec = jobs[f"{name}_yan"].spec["params"]["material"]["glint"]
        # The memory of the reference the quality run rendered: yan_rate^2 lobes per texel.
        rate = int(spec.get("yan_rate", 1))
        ref_side = int(spec["texels_per_uv"]) * int(spec.get("oversample", 1))
        ref_bytes = ref_side * ref_side * rate * rate * LOBE_BYTES
        t_tiny, t_yan = _seconds(jobs[f"{name}_tiny"]), _seconds(jobs[f"{name}_yan"])
        rows.append(
            {
                "type": name,
                "example": stats["example"]["size"],
                "reference": ref_side,
                "rate": rate,
                "flip": metrics["flip"],
                "psnr": metrics["psnr"],
                "ssim": metrics["ssim"],
                "ms_per_spp_tiny": 1e3 * t_tiny,
                "ms_per_spp_yan": 1e3 * t_yan,
                "yan_setup_s": _setup(walls, f"{name}_yan", jobs[f"{name}_yan"]),
                "speedup": t_yan / t_tiny,
                "bytes_tiny": stats["bytes"]["total"],
                "bytes_yan": ref_bytes,
                "paper": PAPER[name],
            }
        )
    print(
        "| type | example | reference | FLIP | PSNR dB | SSIM | tiny ms/spp "
        "| brute-force Yan ms/spp "
        "| speed-up | Yan setup s | tiny MiB | Yan MiB | memory | paper (Table 3) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        print(
            f"| {r['type']} | {r['example']}x{r['example']} | {r['reference']}^2 x {r['rate']}^2 | "
            f"{r['flip']:.3f} | {r['psnr']:.1f} | {r['ssim']:.3f} | {r['ms_per_spp_tiny']:.1f} "
            f"| {r['ms_per_spp_yan']:.1f} | {r['speedup']:.1f}x | {r['yan_setup_s']:.1f} "
            f"| {r['bytes_tiny'] / 2**20:.2f} "
            f"| {r['bytes_yan'] / 2**20:.0f} | {100 * r['bytes_tiny'] / r['bytes_yan']:.2f} % "
            f"| {r['paper']} |"
        )
    ladder = print_ladder(settings, jobs) if "brushed_metal_select" in jobs else None
    closeup = print_closeup(settings, jobs, walls) if "closeup_stochastic_score" in jobs else None
    doc = {"rows": rows, "ladder": ladder, "closeup": closeup, "data_dir": str(data)}
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"\ncommand: .venv/bin/python benchmarks/bench_glint_eval.py; data in {data}")


if __name__ == "__main__":
    main()
