"""Glint figures (Xing et al. 2024, Figs. 8-12) at CPU scale: renders, panels and numbers.

Runs ``scripts/glint_figures.yaml`` step by step in this process (each step through
:func:`service.submission.run_in_process`, ``step:`` refs resolved as ``matforge batch``
does), then writes one PNG panel per figure to ``--figures`` (default
``docs/figures/glints/``) and every number to ``--out`` (JSON), and prints the tables:

- ``fig8.png``, ``fig9.png``: tiny model, Yan reference, the tiny model's HDR-FLIP map
  against it (the score step's ``flip_tiny.png``, magma), Yan at the tiny model's spp and
  its FLIP map (``flip_yan_lo.png``: the Monte Carlo floor), with FLIP, PSNR and SSIM of
  both arms, mean and range over three render seeds each (the panels show the first);
- ``fig10.png``: smooth GGX, structured tiled, scratches tiled, scratches stochastic,
  isotropic noise stochastic;
- ``fig11.png``: brushed metal under five transforms, a row of tiny renders, a row of Yan
  renders, a row of FLIP maps, with the FLIP of each transform's tiny render against the
  tiling's (does the transform change the image?) and Yan at 16 spp against Yan on the
  tiling (the floor);
- ``fig12.png``: the three noise maps (each instance of the stochastic table drawn in a
  colour of its rotation, brighter for larger scale, over one uv square), the renders,
  and the FLIP of noise maps 1 and 2 and of map 0 at another render seed against map 0.

All renders of one figure share one exposure (chosen so that the figure's brightest
reference's 99.5th percentile of luminance maps to 1 before the ACES curve), so that the
panels compare. Times are the render kind's own (its passes, kernel compilation included),
divided by spp.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_glint_figures.py [--data-dir DIR]
[--out glint_figures.json] [--figures DIR] [--var width=64 ...] [--only fig11]``.
``--only`` keeps the steps whose names start with it and the steps they use.
"""

from __future__ import annotations

import argparse
import colorsys
import io
import json
import math
import re
import sys
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

ROOT = Path(__file__).resolve().parent.parent
RECIPE = ROOT / "scripts" / "glint_figures.yaml"
FIGURES = ROOT / "docs" / "figures" / "glints"
#: Pixels between panels, and their colour (white).
GAP = 2
#: Columns of each figure: (label, render step, reference render step or None, score step
#: or None, candidate label in that score).
FIG8 = [("tiny", "fig8_tiny"), ("yan", "fig8_yan"), ("yan_lo", "fig8_yan_lo")]
FIG9 = [("tiny", "fig9_tiny"), ("yan", "fig9_yan"), ("yan_lo", "fig9_yan_lo")]
FIG10 = [
    ("smooth GGX", "fig10_ggx"),
    ("structured, tiled", "fig10_structured"),
    ("scratches, tiled", "fig10_scratches_tiled"),
    ("scratches, stochastic", "fig9_tiny"),
    ("isotropic noise, stochastic", "fig10_flakes"),
]
FIG11 = ["tile", "rotate", "scale", "stretch", "shear"]
FIG11_LABEL = {
    "tile": "tiling (identity)",
    "rotate": "rotation 45 deg",
    "scale": "scale (2, 2)",
    "stretch": "stretch (s_x, s_y) = (2, 0.5)",
    "shear": "shear h_y = 0.75",
}
FIG12 = [("map 0", "fig12_map0"), ("map 1", "fig12_map1"), ("map 2", "fig12_map2")]


def _refs(value: Any) -> Iterable[str]:
    if isinstance(value, str):
        m = re.match(r"^step:([A-Za-z0-9_.-]+)", value)
        if m:
            yield m.group(1)
    elif isinstance(value, dict):
        for v in value.values():
            yield from _refs(v)
    elif isinstance(value, list):
        for v in value:
            yield from _refs(v)


def chosen_steps(steps: list[Any], only: str | None) -> list[Any]:
    """The steps whose names start with ``only``, the renders their figure's panel shows,
    and, transitively, the steps they use, in the recipe's order (all of them when ``only``
    is None)."""
    if only is None:
        return steps
    by_name = {s.name: s for s in steps}
    keep = {s.name for s in steps if s.name.startswith(only)}
    # A panel may show another figure's render (Fig. 10 shows Fig. 9's stochastic scratches).
    if any(k.startswith("fig10_") for k in keep):
        keep.update(s for _, s in FIG10)
    todo = list(keep)
    while todo:
        for ref in _refs(by_name[todo.pop()].spec):
            if ref not in keep:
                keep.add(ref)
                todo.append(ref)
    return [s for s in steps if s.name in keep]


def run_recipe(
    data_dir: Path, variables: dict[str, str], only: str | None = None
) -> tuple[Any, dict[str, Any], dict[str, float]]:
    """Run the recipe's steps in this process; the settings, jobs and wall seconds by step."""
    from service.cli.batch import load_batch
    from service.cli.batch_local import StepFailed, run_steps_in_process
    from service.settings import Settings

    settings = Settings.from_env({}).with_(data_dir=data_dir, pool_processes=1)
    steps = chosen_steps(list(load_batch(RECIPE, variables=variables).steps), only)
    wall: dict[str, float] = {}

    def done(step: Any, job: Any, seconds: float) -> None:
        wall[step.name] = seconds
        print(f"  {step.name}: {seconds:.1f} s", file=sys.stderr, flush=True)

    try:
        jobs = run_steps_in_process(steps, settings, on_step=done)
    except StepFailed as exc:
        sys.exit(str(exc))
    return settings, jobs, wall


def _artifact(settings: Any, job: Any, name: str) -> bytes:
    from storage.artifacts import ArtifactStore

    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def _image(settings: Any, job: Any) -> np.ndarray:
    from storage.formats.exr import read_exr

    with tempfile.NamedTemporaryFile(suffix=".exr") as f:
        f.write(_artifact(settings, job, "image.exr"))
        f.flush()
        return np.asarray(read_exr(f.name, "image.exr"), dtype=np.float32)[..., :3]


def _png(settings: Any, job: Any, name: str) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(_artifact(settings, job, name))) as im:
        return np.asarray(im.convert("RGB"))


def _ms_per_spp(job: Any) -> float:
    m = re.search(r"at (\d+) spp in ([0-9.]+) s", job.message or "")
    if m is None:
        raise ValueError(f"no timing in {job.message!r}")
    return 1e3 * float(m.group(2)) / int(m.group(1))


def spread(values: list[float]) -> dict[str, Any]:
    """Mean, min, max and the values of one arm over its render seeds."""
    return {
        "mean": float(np.mean(values)),
        "min": float(min(values)),
        "max": float(max(values)),
        "values": [float(v) for v in values],
    }


def exposure_for(images: list[np.ndarray]) -> float:
    """Stops that map the 99.5th percentile of luminance of the brightest image to 1."""
    lum = [float(np.percentile(im @ np.array([0.2126, 0.7152, 0.0722]), 99.5)) for im in images]
    top = max(lum)
    return 0.0 if top <= 0.0 else -math.log2(top)


def grid(rows: list[list[np.ndarray]]) -> np.ndarray:
    """Tiles of equal size (uint8 RGB) in rows, white gaps between them (a missing tile,
    ``None``, is left white)."""
    h, w = next(t for r in rows for t in r if t is not None).shape[:2]
    cols = max(len(r) for r in rows)
    out = np.full((len(rows) * (h + GAP) - GAP, cols * (w + GAP) - GAP, 3), 255, np.uint8)
    for i, r in enumerate(rows):
        for j, t in enumerate(r):
            if t is not None:
                y, x = i * (h + GAP), j * (w + GAP)
                out[y : y + h, x : x + w] = t
    return out


def _write(path: Path, rgb8: np.ndarray) -> int:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb8).save(path, optimize=True)
    return path.stat().st_size


def noise_map(normals: np.ndarray, seed: int, texels: int, side: int) -> np.ndarray:
    """One stochastic layout over ``[0, texels]^2`` global texels, ``side`` pixels: each
    instance of :class:`~materials.glints.surface.Surface`'s table (Fig. 3's ownership) in
    the hue of its rotation, brighter for a larger scale; uint8 RGB."""
    from materials.glints.surface import Distribution, Surface

    surf = Surface(normals, Distribution(kind="stochastic", scale_range=(0.8, 1.25), seed=seed))
    y, x = (np.mgrid[0:side, 0:side].astype(np.float64) + 0.5) * (texels / side)
    u = np.stack([x.ravel(), y.ravel()], axis=1)
    out = np.zeros((len(u), 3))
    for inst, mask in surf.owner(u):
        a = inst.transform.a
        scale = math.sqrt(abs(float(np.linalg.det(a))))
        hue = (math.degrees(math.atan2(a[1, 0], a[0, 0])) % 360.0) / 360.0
        value = 0.55 + 0.45 * (scale - 0.8) / 0.45
        out[mask] = colorsys.hsv_to_rgb(hue, 0.7, float(np.clip(value, 0.0, 1.0)))
    return (out.reshape(side, side, 3) * 255 + 0.5).astype(np.uint8)


def _fit(tile: np.ndarray, h: int, w: int) -> np.ndarray:
    """``tile`` centred on a white ``h x w`` tile (cropped if larger)."""
    out = np.full((h, w, 3), 255, np.uint8)
    th, tw = min(h, tile.shape[0]), min(w, tile.shape[1])
    y, x = (h - th) // 2, (w - tw) // 2
    out[y : y + th, x : x + tw] = tile[:th, :tw]
    return out


def make_figures(settings: Any, jobs: dict[str, Any], figures: Path, texels: int) -> dict[str, Any]:
    """Write the panels of every figure whose steps ran; the numbers, by figure."""
    from evaluators.metrics.tonemap import tonemap
    from storage.formats.exr import read_exr

    def metrics(step: str) -> dict[str, Any]:
        return json.loads(_artifact(settings, jobs[step], "metrics.json"))["metrics"]

    def tms(steps: list[str], refs: list[str]) -> dict[str, np.ndarray]:
        imgs = {s: _image(settings, jobs[s]) for s in steps}
        ev = exposure_for([imgs[r] for r in refs])
        return {s: tonemap(im, exposure=ev) for s, im in imgs.items()}

    out: dict[str, Any] = {}
    sizes: dict[str, int] = {}
    for fig, cols, score in (("fig8", FIG8, "fig8_score"), ("fig9", FIG9, "fig9_score")):
        if score not in jobs:
            continue
        steps = [s for _, s in cols]
        t = tms(steps, [steps[1]])
        flip_tiny = _png(settings, jobs[score], "flip_tiny.png")
        flip_lo = _png(settings, jobs[score], "flip_yan_lo.png")
        row = [t[steps[0]], t[steps[1]], flip_tiny, t[steps[2]], flip_lo]
        sizes[fig] = _write(figures / f"{fig}.png", grid([row]))
        m = metrics(score)
        out[fig] = {
            arm: {
                k: spread([m[c][k] for c in m if c == arm or c.startswith(f"{arm}_")])
                for k in ("flip", "psnr", "ssim")
            }
            for arm in ("tiny", "yan_lo")
        }
        out[fig]["ms_per_spp"] = {label: _ms_per_spp(jobs[s]) for label, s in cols}
    if all(s in jobs for _, s in FIG10):
        steps = [s for _, s in FIG10]
        t = tms(steps, steps)
        sizes["fig10"] = _write(figures / "fig10.png", grid([[t[s] for s in steps]]))
        out["fig10"] = {"ms_per_spp": {label: _ms_per_spp(jobs[s]) for label, s in FIG10}}
    if "fig11_effect" in jobs:
        tiny = [f"fig11_{k}_tiny" for k in FIG11]
        yan = [f"fig11_{k}_yan" for k in FIG11]
        t = tms(tiny + yan, yan)
        flips = [_png(settings, jobs[f"fig11_{k}_score"], "flip_tiny.png") for k in FIG11]
        rows = [[t[s] for s in tiny], [t[s] for s in yan], flips]
        sizes["fig11"] = _write(figures / "fig11.png", grid(rows))
        effect = metrics("fig11_effect")
        out["fig11"] = {
            k: {
                "label": FIG11_LABEL[k],
                **{
                    f"{m}_vs_yan": metrics(f"fig11_{k}_score")["tiny"][m]
                    for m in ("flip", "psnr", "ssim")
                },
                "flip_vs_tiling": effect[k]["flip"] if k in effect else None,
                "yan_lo_flip_vs_yan": metrics(f"fig11_{k}_score").get("yan_lo", {}).get("flip"),
                "ms_per_spp_tiny": _ms_per_spp(jobs[f"fig11_{k}_tiny"]),
                "ms_per_spp_yan": _ms_per_spp(jobs[f"fig11_{k}_yan"]),
            }
            for k in FIG11
        }
    if "fig12_score" in jobs:
        steps = [s for _, s in FIG12]
        t = tms(steps, steps)
        h, w = t[steps[0]].shape[:2]
        with tempfile.NamedTemporaryFile(suffix=".exr") as f:
            f.write(_artifact(settings, jobs["aniso"], "example.exr"))
            f.flush()
            normals = np.asarray(read_exr(f.name, "example.exr"), dtype=np.float32)
        side = min(h, w)
        maps = [_fit(noise_map(normals, k, texels, side), h, w) for k in range(len(steps))]
        sizes["fig12"] = _write(figures / "fig12.png", grid([maps, [t[s] for s in steps]]))
        m = metrics("fig12_score")
        out["fig12"] = {
            "flip_vs_map0": {k: m[k]["flip"] for k in ("map0_seed2", "map1", "map2")},
            "psnr_vs_map0": {k: m[k]["psnr"] for k in ("map0_seed2", "map1", "map2")},
            "ms_per_spp": {label: _ms_per_spp(jobs[s]) for label, s in FIG12},
            "mean_radiance": {label: float(_image(settings, jobs[s]).mean()) for label, s in FIG12},
        }
    out["png_bytes"] = sizes
    return out


def print_tables(res: dict[str, Any]) -> None:
    for fig in ("fig8", "fig9"):
        if fig in res:
            r = res[fig]
            ms = r["ms_per_spp"]
            for arm, name in (("tiny", "tiny model"), ("yan_lo", "Yan at the same spp")):
                a = r[arm]
                cells = ", ".join(
                    f"{k} {a[k]['mean']:.3f} ({a[k]['min']:.3f}-{a[k]['max']:.3f})"
                    for k in ("flip", "psnr", "ssim")
                )
                print(f"{fig} {name}, {len(a['flip']['values'])} seeds: {cells}")
            print(f"{fig} ms/spp: " + ", ".join(f"{k} {v:.1f}" for k, v in ms.items()))
    if "fig10" in res:
        print(
            "fig10 ms/spp: "
            + ", ".join(f"{k} {v:.1f}" for k, v in res["fig10"]["ms_per_spp"].items())
        )
    if "fig11" in res:
        print(
            "| transform | FLIP vs Yan | PSNR dB | SSIM | FLIP vs tiling "
            "| tiny ms/spp | Yan ms/spp |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for r in res["fig11"].values():
            fv = "-" if r["flip_vs_tiling"] is None else f"{r['flip_vs_tiling']:.3f}"
            print(
                f"| {r['label']} | {r['flip_vs_yan']:.3f} | {r['psnr_vs_yan']:.1f} | "
                f"{r['ssim_vs_yan']:.3f} | {fv} | {r['ms_per_spp_tiny']:.1f} | "
                f"{r['ms_per_spp_yan']:.1f} |"
            )
    if "fig11" in res and res["fig11"]["tile"]["yan_lo_flip_vs_yan"] is not None:
        print(
            f"fig11 floor: Yan at the tiny model's spp, tiling, FLIP "
            f"{res['fig11']['tile']['yan_lo_flip_vs_yan']:.3f}"
        )
    if "fig12" in res:
        r = res["fig12"]
        print(
            "fig12 FLIP vs map 0: "
            + ", ".join(f"{k} {v:.3f}" for k, v in r["flip_vs_map0"].items())
        )
        print("fig12 ms/spp: " + ", ".join(f"{k} {v:.1f}" for k, v in r["ms_per_spp"].items()))
        print(
            "fig12 mean radiance: "
            + ", ".join(f"{k} {v:.4f}" for k, v in r["mean_radiance"].items())
        )
    print("PNG bytes: " + ", ".join(f"{k} {v:,}" for k, v in res.get("png_bytes", {}).items()))


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("glint_figures.json"))
    parser.add_argument("--figures", type=Path, default=FIGURES, help="where the PNGs go")
    parser.add_argument("--var", action="append", default=[], help="a recipe variable, NAME=VALUE")
    parser.add_argument("--only", default=None, help="steps starting with this, and their inputs")
    args = parser.parse_args(argv)
    variables = dict(v.split("=", 1) for v in args.var)
    data = args.data_dir or Path(tempfile.mkdtemp(prefix="glint_figures-"))
    started = time.perf_counter()
    settings, jobs, wall = run_recipe(data, variables, args.only)
    texels = int(variables.get("texels", "96"))
    res = make_figures(settings, jobs, args.figures, texels)
    res["wall_seconds"] = {"total": time.perf_counter() - started, "steps": wall}
    res["variables"] = variables
    res["data_dir"] = str(data)
    print_tables(res)
    print(f"total {res['wall_seconds']['total']:.0f} s; data in {data}")
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    return res


if __name__ == "__main__":
    main()
