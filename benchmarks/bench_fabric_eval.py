"""Sec. 6 evaluation of the neural woven fabric: quality against the ground truth, and time.

Chen, Wang & Wang 2024, Sec. 6 (Fig. 5, Fig. 8, Table 3): the network against the 256-spp
Monte Carlo ground truth and against the 1-spp and equal-time baselines, on a seen and an
unseen (twill 4x4) material, with FLIP, PSNR, SSIM and MSE; latent interpolation against
directly encoded latents; time per frame.

Runs ``scripts/fabric_eval.yaml`` step by step in-process (each step through
:func:`service.submission.run_in_process`, ``step:`` refs resolved as ``matforge batch``
does), reads the ``score`` steps' ``metrics.json``, then times every frame of the seen and
unseen materials again outside the job (the render kind's own passes, scene built as
``render`` builds it; one warm-up pass compiles the kernel, then the median of
``--repeats`` frames with a host read-back; the 256-spp frame once), and times the encoder
(once per material). The score steps see the whole frame, about a quarter of which is the
environment map behind the cloth (the same in every render); the benchmark also scores
the cloth pixels alone (a mask of pixel-centre camera rays that hit the cloth): MSE, PSNR
(the score step's data range), mean HDR-FLIP (the score step's exposures) and the
relative error of the mean radiance (the bias). It prints a markdown table per material
and the interpolation table, the measured equal-time spp (Monte Carlo frame time taken as
linear in spp through the 1-spp and ground-truth frames), and writes everything as JSON
to ``--out``.

Run: ``.venv/bin/python benchmarks/bench_fabric_eval.py [--data-dir DIR] [--repeats 5]
[--out fabric_eval.json] [--set STEP=JSON ...]``; ``--set`` merges JSON params over a
step's (e.g. ``--set 'model={"preset": "medium"}' --set 'dataset={"sizes": "log_uniform"}'``,
the second pass of issue 12) in a temporary copy of the recipe.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

RECIPE = Path(__file__).resolve().parent.parent / "scripts" / "fabric_eval.yaml"
#: Render steps per material (``<material>_<method>``) and how the table names them.
METHODS = (
    ("net16", "network"),
    ("net1", "network"),
    ("mc1", "Monte Carlo (baseline)"),
    ("mc_eq", "Monte Carlo (equal time with the network's 16 spp)"),
    ("gt", "Monte Carlo (ground truth)"),
)
METRICS = ("flip", "psnr", "ssim", "mse")


class _Refs:
    """``resolve(ref) -> Path`` for ``job:<id>/<name>`` refs of the jobs run here."""

    def __init__(self, store: Any, jobs: dict[str, Any]) -> None:
        self.store, self.by_id = store, {j.id: j for j in jobs.values()}

    def resolve(self, ref: str) -> Path:
        job_id, name = ref.removeprefix("job:").split("/", 1)
        (digest,) = [a.digest for a in self.by_id[job_id].artifacts if a.name == name]
        return Path(self.store.path(digest))


def run_recipe(settings: Any, recipe: Path) -> dict[str, Any]:
    """Run every step of ``recipe`` in order; returns ``{step name: Job}`` (all succeeded)."""
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process

    def done(step: Any, job: Any, seconds: float) -> None:
        print(f"  {step.name}: {seconds:.1f} s", file=sys.stderr)

    try:
        return run_steps_in_process(load_batch(recipe).steps, settings, on_step=done)
    except StepFailed as exc:
        raise SystemExit(str(exc)) from None


def read_json(settings: Any, job: Any, name: str) -> Any:
    """The JSON artifact ``name`` of ``job``."""
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))


def frame_seconds(mi: Any, params: Any, refs: _Refs, repeats: int) -> float:
    """Median seconds per frame of a render step's params, compiled first, read back."""
    from evaluators.render.integrators import integrator_for
    from evaluators.render.kind import plan_passes, render_passes
    from evaluators.render.scenes import SceneSetup, build_scene
    from evaluators.render.sources.common import resolve_material

    width, height = params.resolution
    passes = plan_passes(width, height, params.spp)
    bsdf = resolve_material(params.material, refs, mi)  # type: ignore[arg-type]
    setup = SceneSetup(resolution=(width, height), spp=passes[0], max_depth=params.max_depth)
    scene_dict = build_scene(params.scene, mi, bsdf, setup)
    scene_dict["integrator"] = integrator_for(mi, bsdf, scene_dict["integrator"])
    scene = mi.load_dict(scene_dict)
    render_passes(mi, scene, passes[:1], [0])  # compiles the kernel
    times = []
    for i in range(1 if params.spp >= 64 else repeats):
        started = time.perf_counter()
        render_passes(mi, scene, passes, [i + 1] * len(passes))
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def cloth_mask(mi: Any, params: Any) -> Any:
    """``(H, W)`` bool: the pixels whose centre's camera ray hits the scene's object."""
    import numpy as np

    from evaluators.render.scenes import SceneSetup, build_scene

    width, height = params.resolution
    setup = SceneSetup(resolution=(width, height), spp=1, max_depth=params.max_depth)
    scene = mi.load_dict(build_scene(params.scene, mi, {"type": "diffuse"}, setup))
    i = np.arange(width * height)
    pos = mi.Point2f(((i % width + 0.5) / width).astype(np.float32),
                     ((i // width + 0.5) / height).astype(np.float32))  # fmt: skip
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.0, pos, mi.Point2f(0.5, 0.5))
    return np.asarray(scene.ray_intersect(ray).is_valid()).reshape(height, width)


def cloth_scores(ref: Any, images: dict[str, Any], mask: Any) -> dict[str, dict[str, float]]:
    """Metrics of ``images`` against ``ref`` over the ``mask`` pixels (module docstring)."""
    import numpy as np

    from evaluators.metrics.images import flip, hdr_exposure_range

    exposure, peak = hdr_exposure_range(ref), float(ref.max())
    out = {}
    for label, img in images.items():
        err = float(np.mean((img[mask].astype(np.float64) - ref[mask]) ** 2))
        _, error_map = flip(ref, img, exposure_range=exposure)
        out[label] = {
            "mse": err,
            "psnr": float(10 * np.log10(peak * peak / err)) if err > 0 else float("inf"),
            "flip": float(error_map[mask].mean()),
            "bias": float(img[mask].mean() / ref[mask].mean() - 1.0),
        }
    return out


def encoder_seconds(refs: _Refs, model_ref: str, fabric: dict[str, Any]) -> float:
    """Seconds to encode one material (maps rasterised and the encoder run), median of 3."""
    from evaluators.render.sources.fabric import FabricSpec
    from evaluators.render.sources.fabric_model import latent_for
    from models.fabric.fused import load_fabric_model

    model = load_fabric_model(refs.resolve(model_ref).read_bytes())
    params = FabricSpec.model_validate(fabric, strict=False).to_params()
    times = []
    for _ in range(3):
        started = time.perf_counter()
        latent_for(model, params, model_ref)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def check_seen(settings: Any, jobs: dict[str, Any]) -> str:
    """Which training material the recipe's 'seen' material is (``''``: none, a warning)."""
    from evaluators.render.sources.fabric import FabricSpec

    seen = jobs["seen_gt"].spec["params"]["material"]["fabric"]
    mine = FabricSpec.model_validate(seen, strict=False).to_params()
    for record in read_json(settings, jobs["dataset"], "materials.json")["materials"]:
        theirs = FabricSpec.model_validate(record["params"], strict=False).to_params()
        if theirs == mine:
            return str(record["name"])
    return ""


def overridden_recipe(recipe: Path, sets: list[str]) -> Path:
    """A temporary copy of ``recipe`` with ``STEP=JSON`` params merged over its steps'."""
    import yaml

    doc = yaml.safe_load(recipe.read_text())
    steps = {s["name"]: s for s in doc["steps"]}
    for item in sets:
        name, _, text = item.partition("=")
        spec = steps[name]["spec"]
        spec["params"] = {**spec["params"], **json.loads(text)}
        spec["name"] = f"{spec.get('name', name)} ({text})"
    out = Path(tempfile.mkdtemp(prefix="fabric_recipe_")) / recipe.name
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=None, help="default: a temporary one")
    ap.add_argument("--recipe", type=Path, default=RECIPE)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="STEP=JSON",
                    help="merge JSON params over a recipe step's (repeatable)")  # fmt: skip
    args = ap.parse_args()
    if args.set:
        args.recipe = overridden_recipe(args.recipe, args.set)

    from evaluators.render.kind import RenderParams
    from materials.backend import load_mitsuba
    from service.settings import Settings
    from storage.artifacts import ArtifactStore

    data = args.data_dir or Path(tempfile.mkdtemp(prefix="bench_fabric_eval_"))
    settings = Settings.from_env({}).with_(data_dir=data, lease_seconds=60.0, pool_processes=2)
    load = [os.getloadavg()[0]]
    started = time.perf_counter()
    print(f"running {args.recipe} in {data}", file=sys.stderr)
    jobs = run_recipe(settings, args.recipe)
    recipe_seconds = time.perf_counter() - started
    load.append(os.getloadavg()[0])
    seen_name = check_seen(settings, jobs)
    if not seen_name:
        print("WARNING: the 'seen' material is not one of the dataset's", file=sys.stderr)

    mi = load_mitsuba()
    refs = _Refs(ArtifactStore(settings.store_dir), jobs)
    result: dict[str, Any] = {
        "recipe": str(args.recipe),
        "recipe_seconds": recipe_seconds,
        "seen_material": seen_name,
        "training": read_json(settings, jobs["model"], "metrics.json")["mean"],
        "materials": {},
    }
    from storage.formats.exr import read_exr

    def image(step: str) -> Any:
        (digest,) = [a.digest for a in jobs[step].artifacts if a.name == "image.exr"]
        return read_exr(refs.store.path(digest))

    mask = cloth_mask(mi, RenderParams.model_validate(jobs["seen_gt"].spec["params"]))
    result["cloth_fraction"] = float(mask.mean())
    for key in ("seen", "unseen"):
        scores = read_json(settings, jobs[f"{key}_scores"], "metrics.json")["metrics"]
        cloth = cloth_scores(
            image(f"{key}_gt"), {m: image(f"{key}_{m}") for m, _ in METHODS if m != "gt"}, mask
        )
        rows = {}
        for method, label in METHODS:
            params = RenderParams.model_validate(jobs[f"{key}_{method}"].spec["params"])
            seconds = frame_seconds(mi, params, refs, args.repeats)
            load.append(os.getloadavg()[0])
            rows[method] = {"label": label, "spp": params.spp, "seconds": seconds,
                            **scores.get(method, {}), "cloth": cloth.get(method)}  # fmt: skip
        spread = max(rows["gt"]["spp"] - rows["mc1"]["spp"], 1)
        mc_per_spp = (rows["gt"]["seconds"] - rows["mc1"]["seconds"]) / spread
        mc_fixed = rows["mc1"]["seconds"] - mc_per_spp
        fabric = jobs[f"{key}_gt"].spec["params"]["material"]["fabric"]
        model_ref = jobs[f"{key}_net16"].spec["params"]["material"]["model"]
        result["materials"][key] = {
            "pattern": fabric["pattern"],
            "rows": rows,
            "equal_time_spp": (rows["net16"]["seconds"] - mc_fixed) / max(mc_per_spp, 1e-9),
            "encoder_seconds": encoder_seconds(refs, model_ref, fabric),
        }
    vs_direct = read_json(settings, jobs["interp_vs_direct"], "metrics.json")["metrics"]
    direct = image("interp_direct")
    result["interpolation"] = {
        "vs_gt": read_json(settings, jobs["interp_scores"], "metrics.json")["metrics"],
        "vs_direct": vs_direct,
        "cloth_vs_gt": cloth_scores(
            image("interp_gt"), {"interpolated": image("interp_lerp"), "direct": direct}, mask
        ),
        "gt_scale": read_json(settings, jobs["interp_gt_scale"], "metrics.json")["metrics"],
        "cloth_gt_scale": cloth_scores(
            image("interp_gt"),
            {k: image(f"interp_gt_{k}") for k in ("beta_0_2", "beta_0_8")},
            mask,
        ),
        "cloth_vs_direct": cloth_scores(
            direct,
            {k: image(f"interp_{'lerp' if k == 'interpolated' else k}") for k in vs_direct},
            mask,
        ),
    }
    result["load"] = [min(load), max(load)]
    report(result)
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))


def report(result: dict[str, Any]) -> None:
    """Print the markdown tables of ``result``."""
    print(f"recipe {result['recipe']} in-process: {result['recipe_seconds']:.0f} s; "
          f"load {result['load'][0]:.1f}-{result['load'][1]:.1f}; seen material "
          f"{result['seen_material'] or 'NOT IN THE DATASET'}")  # fmt: skip
    print("\n| material | method | s/frame | FLIP | PSNR (dB) | SSIM | MSE |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for key, mat in result["materials"].items():
        for row in mat["rows"].values():
            figures = " | ".join(
                "(reference)" if m not in row else f"{row[m]:.4g}" for m in METRICS
            )
            print(f"| {key} ({mat['pattern']}) | {row['label']}, {row['spp']} spp | "
                  f"{row['seconds']:.3f} | {figures} |")  # fmt: skip
    print(f"\nCloth pixels only ({100 * result['cloth_fraction']:.0f} % of the frame):")
    print("\n| material | method | FLIP | PSNR (dB) | MSE | mean radiance vs GT |")
    print("| --- | --- | --- | --- | --- | --- |")
    for key, mat in result["materials"].items():
        for row in mat["rows"].values():
            c = row["cloth"]
            if c is not None:
                print(f"| {key} ({mat['pattern']}) | {row['label']}, {row['spp']} spp | "
                      f"{c['flip']:.4g} | {c['psnr']:.4g} | {c['mse']:.4g} | "
                      f"{100 * c['bias']:+.1f} % |")  # fmt: skip
    for key, mat in result["materials"].items():
        print(f"\n{key}: measured equal-time Monte Carlo spp for the network's 16-spp frame: "
              f"{mat['equal_time_spp']:.2f}; encoder {1e3 * mat['encoder_seconds']:.0f} ms "
              f"once per material")  # fmt: skip
    print("\n| Fig. 8, beta 0.5 | FLIP | PSNR (dB) | SSIM | MSE | cloth FLIP | cloth MSE "
          "| cloth mean radiance vs reference |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    interp = result["interpolation"]
    rows = [(f"{k} vs GT", interp["vs_gt"][k], interp["cloth_vs_gt"][k]) for k in interp["vs_gt"]]
    rows += [
        (f"{k} vs direct", interp["vs_direct"][k], interp["cloth_vs_direct"][k])
        for k in interp["vs_direct"]
    ]
    rows += [
        (f"GT {k} vs GT beta 0.5", interp["gt_scale"][k], interp["cloth_gt_scale"][k])
        for k in interp["gt_scale"]
    ]
    for label, row, cloth in rows:
        whole = " | ".join(f"{row[m]:.4g}" for m in METRICS)
        part = f"{cloth['flip']:.4g} | {cloth['mse']:.4g} | {100 * cloth['bias']:+.1f} %"
        print(f"| {label} | {whole} | {part} |")
    print("\n`.venv/bin/python benchmarks/bench_fabric_eval.py`")


if __name__ == "__main__":
    main()
