"""``evaluate.tss``: texture-space shading with temporal reuse (Xu et al. 2025, "Real-Time
Neural Materials on Mobile VR", Sec. 3.2, 4.2; Table 2 and Fig. 6).

A trained BTF model (``train.btf``) covers a plane, ``uv_scale`` repeats per side, under
point lights, seen by a VR head's seeded smooth motion (:mod:`evaluators.tss.path`). For each
radiance-texture resolution ``R`` and update interval ``N`` the radiance texture is shaded
every ``N + 1`` frames and every frame looks it up; each frame is scored against per-frame
screen-space shading, and every pass is timed (:mod:`evaluators.tss.simulate`,
:mod:`evaluators.tss.passes`).

Radiance-texture resolutions: ``R x R`` texels over the whole plane. Texel-matched
(``R`` = model resolution x ``uv_scale``, the small preset's default) the pass is the paper's
:meth:`FusedBtf.shade_texture` (``texture_pass`` ``amortised``: the student's coarse MLP
once per 2 x 2 block); any other ``R`` evaluates :meth:`FusedBtf.eval` at the ``R x R``
texel centres (neural features bilinear), as does ``texture_pass`` ``per_texel``.
``texture_pass`` ``amortised_all`` runs the student's 2 x 2 amortisation at every even ``R``
(the coarse MLP once per 2 x 2 block of the radiance texture, at the block centre's
directions; :meth:`evaluators.tss.passes.Plane.amortises`), so a table of several ``R``
compares one pass; ``amortised`` (the default, kept so earlier specs give the same bytes)
amortises only where texel-matched.

==================  ========================================================================
artifact            content
==================  ========================================================================
``metrics.json``    one row per ``(R, N)``: ``flip_mean``, ``flip_max`` (over frames of each
                    frame's mean HDR-FLIP), ``psnr_mean``, ``psnr_min``, ``shading_passes``
                    (``ceil(frames / (N + 1))``), ``pass``; per-frame FLIP and PSNR; the
                    path's motion per frame; settings. Deterministic per spec.
``timing.json``     per row ``seconds_per_frame`` and ``relative_cost`` (kernel time; shading
                    / (N + 1) + lookup, over screen space), their wall-time twins, median
                    seconds of each pass, the machine. Varies between runs: with
                    ``table.png`` that plots it, a declared timing artifact
                    (``timing_artifacts``), since the kind's product is a measured cost.
``path.json``       the cameras of every frame and the frames each ``N`` shaded at
``table.png``       FLIP against relative cost, a line per ``R``, points labelled ``N``
``frames.png``      Fig. 6: screen-space reference, each ``R``'s frame at N = 4 (or the
                    largest N), the FLIP maps
==================  ========================================================================
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Any

from evaluators.tss.document import TssMetrics, TssPath, TssTiming
from evaluators.tss.params import PLANE_SIDE, ExternalBtfRef, TssParams
from evaluators.tss.rows import ROW_METRICS, tss_rows
from jobapi.documents import read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.params import job_id_of
from jobapi.results import ArtifactReader, ResultTable

if TYPE_CHECKING:
    from evaluators.tss.simulate import Simulation
    from jobapi.context import JobContext
    from models.btf.portable import PortableBtf

FORMAT = "matforge.tss/1"
#: Columns of the result table.
COLUMNS = ("flip_mean", "flip_max", "psnr_mean", "shading_passes", "seconds_per_frame",
           "relative_cost")  # fmt: skip
LAYOUT = """
- `metrics.json`: `rows` `[{label: "<R>/N=<N>", resolution, interval, pass, flip_mean,
  flip_max, psnr_mean, psnr_min, shading_passes}]` (FLIP: HDR-FLIP per frame, then mean and
  max over frames; PSNR `null` where a frame equals its reference); `per_frame` `{label:
  {flip: [...], psnr: [...]}}`; `motion` per frame; `settings`. Deterministic per spec.
- `timing.json`: `rows` `{label: {seconds_per_frame, relative_cost, wall_seconds_per_frame,
  wall_relative_cost}}`, `passes` (median seconds), `environment`; varies between runs.
- `table.png`: FLIP against `relative_cost`. With `timing.json`, the kind's timing artifacts:
  its product is a measured cost, so these two are the exception to "same spec, same
  bytes" (every other artifact holds to it).
- `path.json`: `eye` `(F, 3)`, `basis` `(F, 3, 3)` rows right, up, forward (world, z up,
  metres), `tan_half_fov`, `shading_frames` `{N: [frames]}`.
"""


def label_of(resolution: int, interval: int) -> str:
    """The row label of ``(R, N)``: ``"32/N=4"``."""
    return f"{resolution}/N={interval}"


def load_model(params: TssParams, ctx: JobContext) -> PortableBtf:
    """The portable model of the ``train.btf`` job ``params.model``; ``JobFailed`` naming
    ``model`` otherwise."""
    from models.btf.portable import read_model, read_textures

    assert isinstance(params.model, str)
    job_id = job_id_of(params.model)
    ctx.input_job(job_id, "model", "train.btf")
    try:
        doc = json.loads(ctx.read_ref(f"job:{job_id}/model.json"))
        return read_model(doc, read_textures(ctx.read_ref(f"job:{job_id}/textures.npz")))
    except JobFailed as exc:
        raise JobFailed(f"model: {exc}") from None
    except (ValueError, OSError) as exc:
        raise JobFailed(f"model: {exc}") from None


def _rounded(x: float, digits: int) -> float | None:
    return round(float(x), digits) if math.isfinite(x) else None


def metrics_document(params: TssParams, model: PortableBtf | Any, sim: Simulation,
                     motion: dict[str, float]) -> dict[str, Any]:  # fmt: skip
    """``metrics.json``: everything deterministic."""
    rows, per_frame = [], {}
    for (r, n), s in sim.series.items():
        label = label_of(r, n)
        psnrs = [_rounded(p, 4) for p in s.psnr]
        finite = [p for p in s.psnr if math.isfinite(p)]
        # PSNR of a frame equal to its reference is infinite: the mean is then null.
        psnr_mean = sum(finite) / len(finite) if len(finite) == len(s.psnr) else math.inf
        rows.append(
            {
                "label": label,
                "resolution": r,
                "interval": n,
                "pass": "amortised" if sim.amortised[r] else "per_texel",
                "flip_mean": round(sum(s.flip) / len(s.flip), 6),
                "flip_max": round(max(s.flip), 6),
                "psnr_mean": _rounded(psnr_mean, 4),
                "psnr_min": _rounded(min(s.psnr), 4),
                "shading_passes": len(s.shading_frames),
            }
        )
        per_frame[label] = {"flip": [round(f, 6) for f in s.flip], "psnr": psnrs}
    h, w = model.resolution
    return {
        "format": FORMAT,
        "model": {
            "job": params.model if isinstance(params.model, str) else None,
            "external": None
            if isinstance(params.model, str)
            else params.model.external.model_dump(mode="json", exclude_none=True),
            "runtime": str(getattr(model, "runtime", "drjit-fused")),
            "model": model.model,
            "kind": model.kind,
            "resolution": [h, w],
        },
        "rows": rows,
        "per_frame": per_frame,
        "motion": motion,
        "figure": {"frame": sim.figure.frame, "interval": sim.figure.interval},
        "settings": {
            "frames": params.effective().frames,
            "image": list(params.effective().image),
            "resolutions": sorted({r for r, _ in sim.series}),
            "intervals": list(params.intervals),
            "uv_scale": params.uv_scale,
            "plane_side_m": PLANE_SIDE,
            "lights": [li.model_dump(mode="json") for li in params.lights],
            "path": params.path.model_dump(mode="json"),
            "texture_pass": params.texture_pass,
            "flip": {
                "mode": "hdr",
                "ppd": params.flip_ppd,
                "exposure": "per frame, from the reference's non-black pixels",
            },
            "psnr_peak": "the frame's reference maximum",
            "flip_max": "largest per-frame mean FLIP",
        },
    }


def timing_document(sim: Simulation, threads: int) -> dict[str, Any]:
    """``timing.json``: the measured costs (vary between runs)."""
    from models.speed import environment

    rows = {}
    for r, n in sim.series:
        c = sim.timings.costs(r, n)
        rows[label_of(r, n)] = {
            "seconds_per_frame": c["kernel_seconds_per_frame"],
            "relative_cost": _rounded(c["kernel_relative_cost"], 6),
            "wall_seconds_per_frame": c["wall_seconds_per_frame"],
            "wall_relative_cost": _rounded(c["wall_relative_cost"], 6),
        }
    return {
        "format": FORMAT,
        "rows": rows,
        "passes": sim.timings.medians(),
        "environment": environment(threads),
        "units": {
            "seconds_per_frame": "median shading-pass kernel seconds / (N + 1) + median "
            "lookup-pass kernel seconds (Dr.Jit kernel history, plus the seconds inside "
            "onnxruntime for an ONNX model; warm-up excluded)",
            "relative_cost": "seconds_per_frame / median screen-space pass kernel seconds",
            "wall_*": "the same from wall time: tracing + launch + sync (dr.sync_thread)",
        },
        "note": "varies from run to run; the one non-deterministic artifact (with table.png)",
    }


def run_evaluate_tss(params: TssParams, ctx: JobContext) -> None:
    """Load the model, simulate every ``(R, N)`` and store the artifacts."""
    from evaluators.tss.figures import frames_png, table_png
    from evaluators.tss.passes import Plane
    from evaluators.tss.path import camera_path
    from evaluators.tss.simulate import simulate
    from materials.backend import load_mitsuba
    from models.btf.fused import FusedBtf

    ctx.progress(0.0, "loading the model")
    mi = load_mitsuba()
    if not mi.variant().startswith(("llvm_", "cuda_")):
        raise JobFailed(
            "evaluate.tss needs a vectorised Mitsuba variant (llvm_ad_rgb or cuda_ad_rgb; "
            f"MATFORGE_VARIANT); got {mi.variant()}"
        )
    if isinstance(params.model, ExternalBtfRef):
        from evaluators.tss.external import load_external_btf

        model: Any = load_external_btf(params.model.external.model_dump(), ctx, mi)
        fused: Any = model
    else:
        model = load_model(params, ctx)
        fused = FusedBtf(model, mi)
    h, w = model.resolution
    resolutions = params.texture_resolutions(max(h, w))
    eff = params.effective()
    frames, size = eff.frames, eff.image
    path = camera_path(params.path, frames, ctx.rng("evaluate.tss/path"))
    if float(path.eye[:, 2].min()) <= 0.0:
        raise JobFailed("path: the eye goes below the plane; lower the motion amplitudes")
    plane = Plane(fused, params.lights, params.uv_scale)
    ctx.progress(0.05, f"{frames} frames, R = {resolutions}, N = {params.intervals}")

    def progress(fraction: float, message: str) -> None:
        ctx.progress(0.05 + 0.85 * fraction, message)

    sim = simulate(plane, path, resolutions, params.intervals, (int(size[0]), int(size[1])),
                   amortised=params.texture_pass != "per_texel",
                   everywhere=params.texture_pass == "amortised_all", ppd=params.flip_ppd,
                   progress=progress)  # fmt: skip
    metrics = metrics_document(params, model, sim, path.motion())
    timing = timing_document(sim, plane.dr.thread_count())
    ctx.put_json("metrics.json", metrics)
    ctx.put_json("timing.json", timing)
    shading = {str(n): sim.series[(resolutions[0], n)].shading_frames for n in params.intervals}
    ctx.put_json("path.json", path.document(shading))
    ctx.progress(0.95, "figures")
    plot_rows = [{**row, "relative_cost": timing["rows"][row["label"]]["relative_cost"]}
                 for row in metrics["rows"]]  # fmt: skip
    name = f"{model.model} {h}x{w}, uv x{params.uv_scale}"
    ctx.put_bytes("table.png", table_png(plot_rows, f"evaluate.tss: {name}, {frames} frames"),
                  "image/png")  # fmt: skip
    ctx.put_bytes("frames.png", frames_png(sim.figure, f"evaluate.tss: {name}"), "image/png")
    best = min(metrics["rows"], key=lambda row: row["flip_mean"])
    ctx.progress(1.0, f"{len(metrics['rows'])} configurations; lowest FLIP {best['flip_mean']:.4f} "
                 f"at {best['label']}")  # fmt: skip


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row per ``(R, N)`` (``metrics.json`` with ``timing.json``'s costs) and a
    ``screen space`` row (FLIP 0, relative cost 1)."""
    doc = read_typed(read("metrics.json"), TssMetrics)
    if doc is None:
        return None
    timing = read_typed(read("timing.json"), TssTiming)
    costs = timing["rows"] if timing is not None else {}
    rows: dict[str, dict[str, Any]] = {}
    for row in doc["rows"]:
        found: dict[str, Any] = {**costs.get(row["label"], {}), **row}
        rows[row["label"]] = {c: found.get(c) for c in COLUMNS}
    screen = timing["passes"]["screen_space"]["kernel_s"] if timing is not None else None
    rows["screen space"] = {"flip_mean": 0.0, "flip_max": 0.0, "psnr_mean": None,
                            "shading_passes": doc["settings"].get("frames"),
                            "seconds_per_frame": screen, "relative_cost": 1.0}  # fmt: skip
    return ResultTable(
        title="Texture-space shading (Table 2)", label_header="R / interval",
        columns=list(COLUMNS), rows=rows, reference="per-frame screen-space shading",
        settings=doc["settings"],
    )  # fmt: skip


register(
    Kind(
        name="evaluate.tss",
        variant_bytes=True,
        params=TssParams,
        runner=run_evaluate_tss,
        description="Texture-space shading of a train.btf model with the radiance texture "
        "reused for N frames (Xu et al. 2025, Sec. 4.2): FLIP/PSNR against per-frame "
        "screen-space shading over a seeded VR head path, and the cost per frame (Table 2, "
        "Fig. 6).",
        artifacts=("metrics.json", "timing.json", "path.json", "table.png", "frames.png"),
        # Its product is a measured cost (Table 2): the costs and the plot of FLIP against
        # them vary between runs; every other artifact is the same bytes for the same spec.
        timing_artifacts=("timing.json", "table.png"),
        smoke={"model": "step:train.btf", "frames": 6, "intervals": [0, 2], "image": [32, 32]},
        figures=(
            Figure(
                "frames.png",
                caption=(
                    "Screen-space reference, each interval's frame and their FLIP maps (Fig. "
                    "6's layout)."
                ),
                lead=True,
            ),
        ),
        documents={"metrics.json": TssMetrics, "timing.json": TssTiming, "path.json": TssPath},
        summary=summarize,
        rows=tss_rows,
        metrics=ROW_METRICS,
        layout=LAYOUT,
    )
)
