"""The simulation of ``evaluate.tss``: texture-space shading reused over frames (Sec. 4.2)
against per-frame screen-space shading, scored with FLIP and PSNR and timed.

For each texture resolution ``R`` and update interval ``N``, frame ``k`` of the camera path
is looked up (:meth:`Plane.lookup`, at frame ``k``'s camera) in the radiance texture shaded
at frame ``s = k - (k mod (N + 1))`` (:meth:`Plane.shade`, at frame ``s``'s eye): the
texture is shaded every ``N + 1`` frames, ``ceil(frames / (N + 1))`` passes in all. The
reference of frame ``k`` is :meth:`Plane.reference` at frame ``k``. A texture shaded at
frame ``s`` does not depend on ``N``, so one pass serves every ``N`` that shades at ``s``.

Scores per frame: HDR-FLIP (the exposure range derived once from the frame's reference, from
its non-black pixels, and used for every candidate of that frame) and PSNR (peak: the
reference's largest value).

Cost (the analogue of Table 2's FPS): each pass is timed around ``dr.eval`` and
``dr.sync_thread`` (Dr.Jit is lazy and asynchronous: ``../shared/NOTES.md``), after an
untimed warm-up of every pass that compiles its kernel (cameras are opaque values, so the
kernels are reused). Both the wall time (tracing the Python code, launching, waiting) and the
kernels' own execution time (Dr.Jit's kernel history: what a renderer pays per pass) are
kept. A model that runs in another runtime (an ONNX BTF: onnxruntime, called from the
pass) adds the seconds spent inside that runtime to the pass's kernel seconds. Seconds per
frame = median shading pass / (N + 1) + median lookup pass, and relative cost = that /
median screen-space pass.
"""

from __future__ import annotations

import hashlib
import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from evaluators.metrics.images import flip, hdr_exposure_range, psnr
from evaluators.tss.passes import Plane
from evaluators.tss.path import CameraPath
from jobapi.errors import JobFailed

#: ``on_frame(k, reference, {(R, N): frame})``: every frame's images, ``(H, W, 3)`` float32.
FrameHook = Callable[[int, np.ndarray, dict[tuple[int, int], np.ndarray]], None]


@dataclass
class Series:
    """One ``(R, N)`` configuration: per-frame scores and the frames it shaded at."""

    flip: list[float] = field(default_factory=list)
    psnr: list[float] = field(default_factory=list)
    shading_frames: list[int] = field(default_factory=list)


@dataclass
class Figure:
    """Fig. 6's material: frame ``frame``'s reference, and per resolution the frame at
    interval ``interval`` with its FLIP map."""

    frame: int
    interval: int
    reference: np.ndarray | None = None
    frames: dict[int, np.ndarray] = field(default_factory=dict)
    flip_maps: dict[int, np.ndarray] = field(default_factory=dict)


@dataclass
class Timings:
    """``(wall_s, kernel_s)`` of every timed pass."""

    shade: dict[int, list[tuple[float, float]]]
    lookup: dict[int, list[tuple[float, float]]]
    reference: list[tuple[float, float]] = field(default_factory=list)

    def costs(self, resolution: int, interval: int) -> dict[str, float]:
        """Seconds per frame and relative cost of ``(R, N)``, from kernel and wall times."""
        out: dict[str, float] = {}
        for j, name in ((1, "kernel"), (0, "wall")):
            shade = statistics.median(t[j] for t in self.shade[resolution])
            look = statistics.median(t[j] for t in self.lookup[resolution])
            screen = statistics.median(t[j] for t in self.reference)
            spf = shade / (interval + 1) + look
            out[f"{name}_seconds_per_frame"] = spf
            out[f"{name}_relative_cost"] = spf / screen if screen > 0 else math.nan
        return out

    def medians(self) -> dict[str, Any]:
        """Median seconds of each pass (kernel and wall)."""

        def med(ts: list[tuple[float, float]]) -> dict[str, float]:
            return {"kernel_s": statistics.median(t[1] for t in ts),
                    "wall_s": statistics.median(t[0] for t in ts), "count": len(ts)}  # fmt: skip

        return {
            "screen_space": med(self.reference),
            "shading": {str(r): med(ts) for r, ts in self.shade.items()},
            "lookup": {str(r): med(ts) for r, ts in self.lookup.items()},
        }


@dataclass
class Simulation:
    """Everything :func:`simulate` measured."""

    series: dict[tuple[int, int], Series]
    timings: Timings
    figure: Figure
    amortised: dict[int, bool]


def figure_choice(intervals: Sequence[int], frames: int) -> tuple[int, int]:
    """``(frame, N)`` that ``frames.png`` shows: N = 4 (the paper's choice) if simulated,
    else the largest N; the last frame that reuses the texture longest (``k mod (N + 1) =
    N``), else the last frame."""
    n = 4 if 4 in intervals else max(intervals)
    stale = [k for k in range(frames) if k % (n + 1) == n]
    return (stale[-1] if stale else frames - 1), n


class _Clock:
    """Times Dr.Jit passes: wall seconds and the JIT kernels' execution seconds, plus the
    seconds ``outside()`` reports for the pass (a model evaluated by another runtime, such
    as onnxruntime, called from the pass: its execution is the model's kernel time)."""

    def __init__(self, dr: Any, outside: Callable[[], float] | None = None) -> None:
        self.dr = dr
        self.outside = outside

    def run(self, build: Callable[[], list[Any]]) -> tuple[list[Any], float, float]:
        dr = self.dr
        dr.kernel_history_clear()
        before = self.outside() if self.outside is not None else 0.0
        start = time.perf_counter()
        outs = build()
        dr.eval(outs)
        dr.sync_thread()
        wall = time.perf_counter() - start
        hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        extra = self.outside() - before if self.outside is not None else 0.0
        return outs, wall, sum(k["execution_time"] for k in hist) * 1e-3 + extra


def simulate(
    plane: Plane,
    path: CameraPath,
    resolutions: Sequence[int],
    intervals: Sequence[int],
    size: tuple[int, int],
    *,
    amortised: bool = True,
    everywhere: bool = False,
    ppd: float,
    on_frame: FrameHook | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> Simulation:
    """Run every ``(R, N)`` over ``path`` at ``size = (W, H)`` pixels (see the module
    docstring). ``JobFailed`` (naming ``path``) if a frame's reference is black."""
    dr = plane.dr
    width, height = size
    frames = path.frames
    fig_frame, fig_n = figure_choice(intervals, frames)
    series = {(r, n): Series() for r in resolutions for n in intervals}
    timings = Timings(shade={r: [] for r in resolutions}, lookup={r: [] for r in resolutions})
    figure = Figure(fig_frame, fig_n)

    def cam(k: int) -> Any:
        return plane.camera(path.eye[k], path.basis[k], path.tan_half_fov)

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    clock = _Clock(dr, getattr(plane.fused, "outside_seconds", None))
    try:
        # Warm-up: every kernel compiled once, untimed.
        c0 = cam(0)
        clock.run(partial(plane.reference, c0, size))
        for r in resolutions:
            tex, _, _ = clock.run(
                partial(plane.shade, r, c0, amortised=amortised, everywhere=everywhere)
            )
            clock.run(partial(plane.lookup, tex, r, c0, size))
        textures: dict[int, dict[int, list[Any]]] = {r: {} for r in resolutions}
        for k in range(frames):
            ck = cam(k)
            chans, wall, kern = clock.run(partial(plane.reference, ck, size))
            timings.reference.append((wall, kern))
            ref = plane.image(chans, width, height)
            peak = float(ref.max())
            if not peak > 0.0:
                raise JobFailed(f"path: frame {k} sees no lit part of the plane (black)")
            # HDR-FLIP's exposures from the plane's lit pixels: a black background would
            # pull the median luminance to 0 and stretch the range by tens of stops.
            exposure = hdr_exposure_range(ref[ref.max(axis=2) > 0.0][None])
            shown: dict[tuple[int, int], np.ndarray] = {}
            for r in resolutions:
                if any(k % (n + 1) == 0 for n in intervals):
                    tex, wall, kern = clock.run(
                        partial(plane.shade, r, ck, amortised=amortised, everywhere=everywhere)
                    )
                    timings.shade[r].append((wall, kern))
                    textures[r][k] = tex
                source = {n: k - k % (n + 1) for n in intervals}
                scored: dict[bytes, tuple[float, float, np.ndarray]] = {}
                by_source: dict[int, tuple[np.ndarray, bytes]] = {}
                for s in sorted(set(source.values())):
                    chans, wall, kern = clock.run(
                        partial(plane.lookup, textures[r][s], r, ck, size)
                    )
                    timings.lookup[r].append((wall, kern))
                    img = plane.image(chans, width, height)
                    key = hashlib.sha256(img.tobytes()).digest()
                    if key not in scored:  # identical frames are scored once
                        mean, emap = flip(ref, img, mode="hdr", exposure_range=exposure, ppd=ppd)
                        scored[key] = (mean, psnr(ref, img, data_range=peak), emap)
                    by_source[s] = (img, key)
                for n, s in source.items():
                    img, key = by_source[s]
                    one = series[(r, n)]
                    one.flip.append(scored[key][0])
                    one.psnr.append(scored[key][1])
                    if s == k:
                        one.shading_frames.append(k)
                    shown[(r, n)] = img
                    if k == fig_frame and n == fig_n:
                        figure.frames[r] = img
                        figure.flip_maps[r] = scored[key][2]
                keep = set(source.values())
                textures[r] = {s: t for s, t in textures[r].items() if s in keep}
            if k == fig_frame:
                figure.reference = ref
            if on_frame is not None:
                on_frame(k, ref, shown)
            if progress is not None:
                progress((k + 1) / frames, f"frame {k + 1}/{frames}")
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    return Simulation(
        series=series,
        timings=timings,
        figure=figure,
        amortised={r: amortised and plane.amortises(r, everywhere) for r in resolutions},
    )
