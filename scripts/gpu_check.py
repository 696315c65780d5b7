"""The GPU check's driver (``scripts/gpu_check.sh`` runs it; see ``docs/deployment.md``).

Every job runs in its own ``matforge run`` process with ``MATFORGE_VARIANT`` in its
environment, as a worker would (the variant is per process), over one data directory:

1. inputs: the smoke specs of ``generate.merl``, ``.btf``, ``.fabric``, ``.glint`` and of the
   three training kinds, trained with ``device`` set (``cuda``; ``--cpu``: ``cpu``);
2. every material source rendered under ``cuda_ad_rgb`` and ``llvm_ad_rgb`` (the same spec:
   two jobs, since the variant is part of a render's identity), then scored: HDR-FLIP of
   the CUDA image against the LLVM one must stay under :data:`FLIP_BAR`;
3. ``train.brdf``'s ``paper`` preset on the ``merl100`` collection, capped at
   ``--paper-steps`` steps and extrapolated to the preset's 200k, against the paper's 10
   minutes per 100 BRDFs (``--paper``; on by default on a GPU);
4. the BTF student (``c2f``) through ``evaluate.tss`` at 400 x 400: seconds per frame.

Prints one table (step, variant, device, seconds, figure) and writes it as markdown to
``<out>/gpu_check.md``; exits 1 on the first failed job or bar, naming it.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
MATFORGE = REPO / ".venv" / "bin" / "matforge"
#: The most HDR-FLIP between the CUDA and the LLVM render of one spec (issue 29).
FLIP_BAR = 0.01
#: The paper's training time: 10 minutes per 100 BRDFs (Sec. 3.3, 200k steps).
PAPER_SECONDS_PER_100 = 600.0
PAPER_STEPS = 200_000
LLVM, CUDA = "llvm_ad_rgb", "cuda_ad_rgb"


class CheckFailed(RuntimeError):
    """A job failed or a bar was missed; the message names which."""


class Check:
    def __init__(self, data: Path, device: str) -> None:
        self.data, self.device = data, device
        self.rows: list[tuple[str, str, str, float, str]] = []

    def run(self, label: str, spec: dict[str, Any], variant: str) -> dict[str, Any]:
        """Run ``spec`` in a fresh ``matforge run`` under ``variant``; the job document."""
        env = {**os.environ, "MATFORGE_VARIANT": variant, "MATFORGE_DATA": str(self.data)}
        started = time.perf_counter()
        proc = subprocess.run(
            [str(MATFORGE), "run", "-", "--json"],
            input=json.dumps(spec), env=env, capture_output=True, text=True, timeout=1200,
        )  # fmt: skip
        wall = time.perf_counter() - started
        try:
            doc = json.loads(proc.stdout)
        except json.JSONDecodeError:
            doc = {}
        if proc.returncode != 0 or doc.get("state") != "succeeded":
            why = doc.get("error") or (proc.stderr.strip().splitlines() or ["no output"])[-1]
            raise CheckFailed(f"{label} ({variant}): {spec['kind']} failed: {why}")
        run_s = float((doc.get("timings") or {}).get("run_seconds") or wall)
        doc["_seconds"] = run_s
        print(f"  {label:<28} {variant:<12} {run_s:8.2f} s", file=sys.stderr, flush=True)
        return doc

    def artifact(self, job: dict[str, Any], name: str) -> Any:
        """The parsed JSON artifact ``name`` of a finished job."""
        out = self.data / "fetched" / f"{job['id']}-{name.replace('/', '_')}"
        out.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [str(MATFORGE), "fetch", f"job:{job['id']}/{name}", "-o", str(out),
             "--data-dir", str(self.data)],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip
        return json.loads(out.read_text())

    def row(self, step: str, variant: str, seconds: float, figure: str = "") -> None:
        self.rows.append((step, variant, self.device, seconds, figure))


def _first(job: dict[str, Any], suffix: str) -> str:
    names = [a["name"] for a in job["artifacts"] if a["name"].endswith(suffix)]
    if not names:
        raise CheckFailed(f"job {job['id']} has no *{suffix} artifact")
    return names[0]


def inputs(c: Check, variant: str) -> dict[str, dict[str, Any]]:
    """The datasets and trained models the material sources need."""
    from service import kinds

    kinds.load_builtin()
    smoke = {name: dict(k.smoke) for name, k in kinds.all_kinds().items()}
    jobs: dict[str, dict[str, Any]] = {}
    for name in ("generate.merl", "generate.btf", "generate.fabric", "generate.glint"):
        jobs[name] = c.run(name, {"kind": name, "seed": 0, "params": smoke[name]}, variant)
        c.row(name, variant, jobs[name]["_seconds"])
    for name, data_key, source in (
        ("train.brdf", "dataset", "generate.merl"),
        ("train.fabric", "dataset", "generate.fabric"),
        ("train.btf", "data", "generate.btf"),
    ):
        params = {**smoke[name], data_key: f"job:{jobs[source]['id']}", "device": c.device}
        jobs[name] = c.run(f"{name} (small)", {"kind": name, "seed": 0, "params": params}, variant)
        c.row(f"{name} smoke, device {c.device}", variant, jobs[name]["_seconds"])
    return jobs


def materials(c: Check, jobs: dict[str, dict[str, Any]]) -> dict[str, tuple[str, dict]]:
    """One render (scene, material) per material source."""
    model = c.artifact(jobs["train.brdf"], "model.json")
    brdf_material = model["materials"][0]["name"]
    btf, glint = jobs["generate.btf"]["id"], jobs["generate.glint"]["id"]
    return {
        "mitsuba": ("sphere_env", {"mitsuba": {"type": "roughconductor", "alpha": 0.2}}),
        "merl": ("sphere_env", {"merl": f"job:{jobs['generate.merl']['id']}/"
                                        f"{_first(jobs['generate.merl'], '.binary')}"}),
        "model (brdf)": ("sphere_env", {"model": f"job:{jobs['train.brdf']['id']}/model.json",
                                        "material": brdf_material}),
        "fabric": ("cloth_plane", {"fabric": {"pattern": "plain"}}),
        "model (fabric)": ("cloth_plane", {"model": f"job:{jobs['train.fabric']['id']}/model.pt",
                                           "fabric": {"pattern": "plain"}}),
        "glint": ("glint_sphere", {"glint": {"data": f"job:{glint}", "method": "tiny_example"}}),
        "btf": ("plane_points", {"btf": f"job:{btf}", "uv_scale": 4}),
        "model (btf)": ("plane_points", {"model": f"job:{jobs['train.btf']['id']}",
                                         "uv_scale": 4}),
        "btf_surface": ("plane_points", {"btf_surface": f"job:{btf}", "uv_scale": 4}),
    }  # fmt: skip


def renders(c: Check, jobs: dict[str, dict[str, Any]], variants: list[str], size: int,
            spp: int) -> None:  # fmt: skip
    for source, (scene, material) in materials(c, jobs).items():
        spec = {"kind": "render", "seed": 7, "params": {"scene": scene, "material": material,
                "resolution": [size, size], "spp": spp, "max_depth": 4}}  # fmt: skip
        done = {v: c.run(f"render {source}", spec, v) for v in variants}
        figure = ""
        if CUDA in done and LLVM in done:
            if done[CUDA]["id"] == done[LLVM]["id"]:
                raise CheckFailed(f"render {source}: one job for both variants (identity)")
            score = c.run(f"score {source}", {"kind": "score", "params": {
                "reference": f"job:{done[LLVM]['id']}/image.exr",
                "candidates": {"cuda": f"job:{done[CUDA]['id']}/image.exr"},
                "metrics": ["flip"]}}, LLVM)  # fmt: skip
            flip = float(c.artifact(score, "metrics.json")["metrics"]["cuda"]["flip"])
            figure = f"HDR-FLIP cuda vs llvm {flip:.4f} (bar {FLIP_BAR})"
            if not flip < FLIP_BAR:
                raise CheckFailed(f"render {source}: {figure}")
        for v, job in done.items():
            c.row(f"render {source} {size}^2 {spp} spp", v, job["_seconds"], figure)


def paper_brdf(c: Check, variant: str, steps: int) -> None:
    merl = c.run("generate.merl merl100", {"kind": "generate.merl", "seed": 0,
                 "params": {"collection": {"preset": "merl100"}}}, variant)  # fmt: skip
    c.row("generate.merl merl100", variant, merl["_seconds"])
    spec = {"kind": "train.brdf", "seed": 0, "params": {
        "model": "hybrid", "dataset": f"job:{merl['id']}", "preset": "paper",
        "steps": steps, "speed": "off", "device": c.device}}  # fmt: skip
    job = c.run(f"train.brdf paper {steps} steps", spec, variant)
    n = len([a for a in merl["artifacts"] if a["name"].endswith(".binary")])
    projected = job["_seconds"] * PAPER_STEPS / steps * 100 / max(n, 1)
    c.row(f"train.brdf hybrid paper, {n} BRDFs, {steps} steps", variant, job["_seconds"],
          f"projected {projected / 60:.1f} min per 100 BRDFs at 200k steps "
          f"(paper: {PAPER_SECONDS_PER_100 / 60:.0f} min)")  # fmt: skip


def student_frame(
    c: Check, jobs: dict[str, dict[str, Any]], variant: str, size: int, frames: int
) -> None:
    spec = {"kind": "evaluate.tss", "seed": 0, "params": {
        "model": f"job:{jobs['train.btf']['id']}", "frames": frames, "intervals": [0, 2],
        "image": [size, size]}}  # fmt: skip
    job = c.run(f"evaluate.tss c2f {size}^2", spec, variant)
    rows = c.artifact(job, "timing.json")["rows"]
    best = min(float(r["seconds_per_frame"]) for r in rows.values())
    c.row(
        f"BTF student (c2f) frame at {size}^2",
        variant,
        job["_seconds"],
        f"{1000 * best:.2f} ms per frame (kernel, best schedule)",
    )


def table(rows: list[tuple[str, str, str, float, str]]) -> str:
    out = ["| step | variant | device | seconds | figure |", "| --- | --- | --- | ---: | --- |"]
    out += [f"| {s} | {v} | {d} | {t:.2f} | {f} |" for s, v, d, t, f in rows]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cpu", action="store_true", help="llvm_ad_rgb and device cpu only")
    ap.add_argument("--out", type=Path, required=True, help="data directory and report")
    ap.add_argument(
        "--paper",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="time train.brdf's paper preset (default: on with a GPU)",
    )
    ap.add_argument("--paper-steps", type=int, default=4000)
    args = ap.parse_args(argv)
    variants = [LLVM] if args.cpu else [CUDA, LLVM]
    main_variant = variants[0]
    c = Check(args.out / "data", "cpu" if args.cpu else "cuda")
    size, spp = (32, 4) if args.cpu else (128, 16)
    started = time.perf_counter()

    def on_term(*_: object) -> None:  # the shell's `timeout`: report what ran, then fail
        raise CheckFailed(f"stopped by SIGTERM after {time.perf_counter() - started:.0f} s")

    signal.signal(signal.SIGTERM, on_term)
    try:
        jobs = inputs(c, main_variant)
        renders(c, jobs, variants, size, spp)
        if args.paper if args.paper is not None else not args.cpu:
            paper_brdf(c, main_variant, args.paper_steps)
        if args.cpu:
            student_frame(c, jobs, main_variant, 32, 6)
        else:
            student_frame(c, jobs, main_variant, 400, 12)
    except CheckFailed as exc:
        print(f"gpu_check: FAILED: {exc}", file=sys.stderr)
        return 1
    finally:
        report = table(c.rows)
        (args.out / "gpu_check.md").write_text(report + "\n")
        print(report)
    where = "CPU only: nothing ran on a GPU" if args.cpu else "on CUDA"
    print(f"gpu_check: passed in {time.perf_counter() - started:.0f} s ({where})", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
