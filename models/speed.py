"""Speed of the BRDF models: fused Dr.Jit kernel against torch eager, in one run (``speed.json``).

What is measured (all on the CPU, ``threads`` threads for both back ends, float32):

- ``mlp`` rows: the bare MLP of the hybrid model (``6 + l`` inputs, 6 outputs, ReLU),
  :func:`models.fused_mlp.fused_mlp` against the same ``torch.nn.Sequential``;
- ``analytic``, ``hybrid``, ``neural`` rows: the whole BRDF of one material at
  ``(wi, wo)`` pairs: :func:`evaluators.render.bsdfs.brdf_model.model_brdf` (weights and the
  material's
  ``z``, ``kd``, ``eta``, ``alpha`` baked as literals) against the torch model's ``forward``
  (:class:`models.brdf.networks.BrdfModel`, one material).

Sizes: the trained model's own ``width x depth`` (when a ``model.json`` is given) and
:data:`SIZES` (the paper's Table 4: 16x2 ... 64x3), with freshly initialised weights (speed
does not depend on the values). Inputs: ``batch`` cosine-weighted direction pairs, made once.

Timing: each measurement is the median of ``repeats`` runs after one warm-up run.
``fused_ns`` is wall time per evaluation of tracing the Python code, launching the cached
kernel and waiting for it (``dr.sync_thread``: Dr.Jit is lazy and asynchronous);
``fused_kernel_ns`` is the kernel's own execution time from Dr.Jit's kernel history (what a
renderer pays per evaluation once the kernel is traced). The warm-up run's compile time
(LLVM code generation and back end) is reported separately as ``compile_s`` and excluded
from both; Dr.Jit keeps compiled kernels in an on-disk cache (``~/.drjit``), so a network
measured before (same weights, same code) shows ``compile_s`` near 0. ``torch_ns`` is wall
time per evaluation of the eager forward pass under ``torch.inference_mode``.
``speedup = torch_ns / fused_ns``.

CPU time: ``fused_cpu_ns`` is the process CPU time per evaluation of the same kernel,
frozen and replayed (:func:`time_cpu`), divided by the thread count: the time on that many
dedicated cores. On a shared machine the wall figures grow with the load, this one does
not. ``flops`` counts the dense layers' multiply-adds (2 FLOP each, :func:`mlp_flops`; only
the direction inputs are live, the material's latent is folded into the first bias), and
``gflops_per_core`` is ``flops`` over the CPU time per evaluation summed over the threads.
Its fraction of the FP32 FMA peak is :mod:`benchmarks.bench_fused_mlp`'s: the peak is
measured there with a C program (``benchmarks/fma_peak.c``), which a job cannot assume.

Memory: bytes per network = its float32 weights x 4 (the neural model's frame layer
included); bytes per material = its per-material floats x 4 (``z`` plus ``kd``, ``eta``,
``alpha`` for the hybrid).
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from models.fused_mlp import DenseLayer, fused_mlp, parameter_count, random_layers, torch_mlp
from models.timing import cpu_name

#: MLP sizes ``(width, depth)`` of the paper's Table 4.
SIZES: tuple[tuple[int, int], ...] = ((16, 2), (16, 3), (32, 2), (32, 3), (64, 2), (64, 3))
#: Inputs per measurement (2^20) and runs per median.
BATCH = 1 << 20
REPEATS = 7
#: The version tag of the ``speed.json`` document.
SPEED_FORMAT = "matforge.speed/1"


def cosine_pairs(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` independent cosine-weighted pairs ``(wi, wo)``, each ``(n, 3)`` float32, z up."""
    rng = np.random.default_rng(seed)

    def cosine(u: np.ndarray) -> np.ndarray:
        r, phi = np.sqrt(u[:, 0]), 2.0 * math.pi * u[:, 1]
        z = np.sqrt(np.maximum(1.0 - u[:, 0], 0.0))
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)

    return cosine(rng.random((n, 2))), cosine(rng.random((n, 2)))


def time_fused(build: Callable[[], Sequence[Any]], repeats: int = REPEATS) -> dict[str, float]:
    """Time a traced Dr.Jit computation; ``build()`` traces it and returns its outputs.

    Returns ``{"wall_s", "kernel_s", "compile_s"}``: medians over ``repeats`` runs after a
    warm-up whose code generation and back-end time is ``compile_s``.
    """
    import drjit as dr

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        walls, kernels, compile_s = [], [], 0.0
        for rep in range(repeats + 1):
            dr.kernel_history_clear()
            start = time.perf_counter()
            outs = build()
            dr.eval(*outs)
            dr.sync_thread()
            wall = time.perf_counter() - start
            hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            if rep == 0:
                compile_s = sum(k["codegen_time"] + k["backend_time"] for k in hist) * 1e-3
                continue
            walls.append(wall)
            kernels.append(sum(k["execution_time"] for k in hist) * 1e-3)
            del outs
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    return {
        "wall_s": statistics.median(walls),
        "kernel_s": statistics.median(kernels),
        "compile_s": compile_s,
    }


def time_torch(run: Callable[[], Any], repeats: int = REPEATS) -> float:
    """Median wall seconds of ``run()`` (eager torch, inference mode) after one warm-up."""
    import torch

    times = []
    with torch.inference_mode():
        for rep in range(repeats + 1):
            start = time.perf_counter()
            run()
            if rep:
                times.append(time.perf_counter() - start)
    return statistics.median(times)


def time_call(run: Callable[[], Any], repeats: int = REPEATS) -> float:
    """Median wall seconds of ``run()`` after one warm-up (a runtime that is not Dr.Jit's:
    onnxruntime, numpy)."""
    times = []
    for rep in range(repeats + 1):
        start = time.perf_counter()
        run()
        if rep:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def mlp_flops(layers: Sequence[DenseLayer], live_inputs: int | None = None) -> int:
    """Floating-point operations of one evaluation of the network's dense layers: 2 per
    nonzero weight (one fused multiply-add), biases and activations not counted.

    ``live_inputs``: how many leading inputs of the first layer are arrays; the rest are
    per-material constants that :func:`models.fused_mlp.fused_mlp` folds into the bias
    (the hybrid model's latent ``z``), so their weights cost nothing per evaluation.
    """
    first = layers[0].weight[:, : layers[0].n_in if live_inputs is None else live_inputs]
    return 2 * sum(int(np.count_nonzero(w)) for w in (first, *(ly.weight for ly in layers[1:])))


def time_cpu(
    fn: Callable[..., Any], args: Sequence[Any], repeats: int = REPEATS, launches: int = 4
) -> dict[str, float]:
    """Kernel wall time and process CPU time of ``fn(*args)``, frozen with ``dr.freeze``.

    ``fn`` traces a Dr.Jit computation from its array arguments and returns the outputs.
    Frozen, later calls replay the recorded kernel without tracing, so the process CPU time
    around ``launches`` back-to-back calls is the kernel's (plus the thread pool's
    hand-offs), whatever else the machine runs: on a loaded machine the wall time grows
    with the load, the CPU time does not. Returns medians over ``repeats`` of
    ``{"kernel_s", "cpu_s"}`` per call (``kernel_s`` from Dr.Jit's kernel history, wall;
    ``cpu_s`` summed over all threads, so divide by the thread count for the time on
    dedicated cores), after two warm-up calls (record and first replay).
    """
    import drjit as dr

    def run(*xs: Any) -> Any:
        outs = fn(*xs)
        dr.eval(outs)
        return outs

    frozen = dr.freeze(run)
    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    kernels, cpus = [], []
    try:
        for _ in range(2):
            frozen(*args)
            dr.sync_thread()
        for _ in range(repeats):
            dr.kernel_history_clear()
            start = time.process_time()
            for _ in range(launches):
                frozen(*args)
                dr.sync_thread()
            cpus.append((time.process_time() - start) / launches)
            hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            kernels.append(sum(k["execution_time"] for k in hist) * 1e-3 / launches)
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    return {"kernel_s": statistics.median(kernels), "cpu_s": statistics.median(cpus)}


def _row(
    kind: str,
    size: str,
    n: int,
    fused: dict[str, float],
    torch_s: float,
    cpu: dict[str, float],
    flops: int,
    threads: int,
) -> dict[str, Any]:
    fused_ns = fused["wall_s"] / n * 1e9
    torch_ns = torch_s / n * 1e9
    cpu_ns = cpu["cpu_s"] / n * 1e9 / threads
    return {
        "model": kind,
        "size": size,
        "fused_ns": round(fused_ns, 3),
        "fused_kernel_ns": round(fused["kernel_s"] / n * 1e9, 3),
        "fused_cpu_ns": round(cpu_ns, 3),
        "flops": flops,
        "gflops_per_core": round(flops / (cpu_ns * threads), 2) if flops and cpu_ns > 0 else None,
        "torch_ns": round(torch_ns, 3),
        "speedup": round(torch_ns / fused_ns, 3),
        "compile_s": round(fused["compile_s"], 4),
    }


def mlp_row(
    mi: Any,
    layers: Sequence[DenseLayer],
    size: str,
    inputs: np.ndarray,
    repeats: int = REPEATS,
    threads: int = 2,
) -> dict[str, Any]:
    """One ``mlp`` row: ``inputs`` ``(N, n_in)`` float32 through both back ends (all inputs
    live, so ``flops`` counts every weight)."""
    import drjit as dr
    import torch

    cols = [mi.Float(c) for c in np.ascontiguousarray(inputs.T)]
    dr.eval(*cols)
    fused = time_fused(lambda: fused_mlp(layers, cols), repeats)
    cpu = time_cpu(lambda *xs: fused_mlp(layers, list(xs)), cols, repeats, launches=2)
    net, x = torch_mlp(layers), torch.from_numpy(np.ascontiguousarray(inputs))
    torch_s = time_torch(lambda: net(x), repeats)
    row = _row("mlp", size, len(inputs), fused, torch_s, cpu, mlp_flops(layers), threads)
    row["bytes_per_network"] = 4 * parameter_count(layers)
    return row


def environment(threads: int) -> dict[str, Any]:
    """Where the numbers were taken: CPU, threads, load average, versions."""
    import drjit as dr
    import torch

    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return {
        "machine": platform.machine(),
        "processor": cpu_name(),
        "cpus": os.cpu_count(),
        "threads": threads,
        "load_average": [round(v, 2) for v in load],
        "drjit": str(getattr(dr, "__version__", "unknown")),
        "torch": torch.__version__,
        "python": platform.python_version(),
    }


def mlp_speed(
    mi: Any,
    *,
    sizes: Sequence[tuple[int, int]] = SIZES,
    n_in: int = 10,
    n_out: int = 6,
    batch: int = BATCH,
    repeats: int = REPEATS,
    seed: int = 0,
    threads: int = 2,
) -> list[dict[str, Any]]:
    """``mlp`` rows for random ReLU MLPs ``n_in -> width (x depth) -> n_out``."""
    rng = np.random.default_rng(seed)
    inputs = rng.uniform(-1.0, 1.0, (batch, n_in)).astype(np.float32)
    rows = []
    for width, depth in sizes:
        layers = random_layers(rng, n_in, width, depth, n_out)
        rows.append(mlp_row(mi, layers, f"{width}x{depth}", inputs, repeats, threads))
    return rows


# -- whole BRDF models -------------------------------------------------------------------------


def model_row(
    mi: Any,
    model: Any,
    doc: dict[str, Any],
    material: str,
    size: str,
    pairs: tuple[np.ndarray, np.ndarray],
    repeats: int = REPEATS,
    threads: int = 2,
) -> dict[str, Any]:
    """One ``analytic`` / ``hybrid`` / ``neural`` row: material ``material`` of ``doc``
    (fused, baked) against ``model`` (torch, the same weights) at ``pairs``.

    ``flops``: the MLP's with its 6 direction inputs live (0 for the analytic model);
    ``threads`` converts the CPU time to time on dedicated cores (see the module)."""
    import drjit as dr
    import torch

    from models.brdf.fused import bake_material, model_brdf

    baked = bake_material(doc, material)
    index = [m["name"] for m in doc["materials"]].index(material)
    wi_np, wo_np = pairs
    wi, wo = mi.Vector3f(*wi_np.T), mi.Vector3f(*wo_np.T)
    dr.eval(wi, wo)
    fused = time_fused(lambda: [model_brdf(mi, baked, wi, wo)], repeats)
    cpu = time_cpu(lambda a, b: model_brdf(mi, baked, a, b), [wi, wo], repeats, launches=2)
    wi_t, wo_t = torch.from_numpy(wi_np)[None], torch.from_numpy(wo_np)[None]
    idx = torch.tensor([index])
    torch_s = time_torch(lambda: model(wi_t, wo_t, idx).f, repeats)
    flops = mlp_flops(baked.layers, 6) if baked.layers else 0
    row = _row(doc["model"], size, len(wi_np), fused, torch_s, cpu, flops, threads)
    row["bytes_per_network"] = 4 * sum(p.numel() for p in model.network_parameters())
    row["bytes_per_material"] = 4 * int(doc["architecture"]["per_material_params"])
    return row


def _fresh_model(kind: str, width: int, depth: int, latent: int, seed: int) -> tuple[Any, Any]:
    import torch

    from models.brdf.networks import Architecture, build_model
    from models.brdf.portable import to_portable

    arch = Architecture(kind, width, depth, latent)  # type: ignore[arg-type]
    model = build_model(arch, 1, torch.Generator().manual_seed(seed))
    return model, to_portable(model, ["bench"], ["bench"])


def speed_report(
    mi: Any,
    doc: dict[str, Any] | None = None,
    material: str | None = None,
    *,
    sizes: Sequence[tuple[int, int]] = SIZES,
    latent_dim: int = 4,
    batch: int = BATCH,
    repeats: int = REPEATS,
    threads: int = 2,
    seed: int = 0,
) -> dict[str, Any]:
    """The ``speed.json`` document: every row measured in this one call.

    Parameters
    ----------
    mi
        Mitsuba from :func:`materials.backend.load_mitsuba` (a vectorised variant; the
        CPU-time columns mean CPU cores under LLVM only).
    doc, material
        A trained ``model.json`` document and one of its materials (default: its first):
        adds ``trained`` rows at the model's own size, with its real weights.
    sizes
        ``(width, depth)`` of the fresh-weight rows; ``latent_dim`` their hybrid ``l``
        (the neural baseline gets ``l + 7``, the same per-material float count).
    batch, repeats, threads, seed
        Pairs per measurement, runs per median, CPU threads (Dr.Jit and torch), input seed.
    """
    import drjit as dr
    import torch

    from models.brdf.networks import equal_neural_latent
    from models.brdf.portable import from_portable

    old_threads = (torch.get_num_threads(), dr.thread_count())
    torch.set_num_threads(threads)
    dr.set_thread_count(threads)
    try:
        pairs = cosine_pairs(batch, seed)
        rows: list[dict[str, Any]] = []
        if doc is not None:
            model, names, _ = from_portable(doc)
            name = material or names[0]
            a = doc["architecture"]
            size = "-" if doc["model"] == "analytic" else f"{a['width']}x{a['depth']}"
            row = model_row(mi, model, doc, name, size, pairs, repeats, threads)
            rows.append({**row, "trained": True, "material": name})
        model, fresh = _fresh_model("analytic", 0, 0, 0, seed)
        rows.append(model_row(mi, model, fresh, "bench", "-", pairs, repeats, threads))
        rows += mlp_speed(
            mi, sizes=sizes, n_in=6 + latent_dim, batch=batch, repeats=repeats, threads=threads
        )
        for kind, latent in (("hybrid", latent_dim), ("neural", equal_neural_latent(latent_dim))):
            for width, depth in sizes:
                model, fresh = _fresh_model(kind, width, depth, latent, seed)
                size = f"{width}x{depth}"
                rows.append(model_row(mi, model, fresh, "bench", size, pairs, repeats, threads))
    finally:
        torch.set_num_threads(old_threads[0])
        dr.set_thread_count(old_threads[1])
    return {
        "format": SPEED_FORMAT,
        "batch": batch,
        "repeats": repeats,
        "latent_dim": latent_dim,
        "environment": environment(threads),
        "units": {
            "fused_ns": "ns per evaluation, wall: trace + cached kernel + sync (median)",
            "fused_kernel_ns": "ns per evaluation, kernel execution only (median)",
            "fused_cpu_ns": "ns per evaluation on `threads` dedicated cores: process CPU "
            "time of the frozen kernel / threads (median)",
            "flops": "FLOP per evaluation: 2 per multiply-add of the dense layers (live "
            "inputs only)",
            "gflops_per_core": "flops / CPU time per evaluation summed over threads; its "
            "fraction of the FMA peak: benchmarks/bench_fused_mlp.py",
            "torch_ns": "ns per evaluation, torch eager forward, inference mode (median)",
            "compile_s": "first run's LLVM code generation + back end, seconds",
            "bytes_per_network": "float32 weights x 4 (shared by all materials)",
            "bytes_per_material": "per-material floats x 4",
        },
        "notes": "fused rows bake one material's z, kd, eta, alpha as literals (z folded "
        "into the first bias; the neural model's constant frames into its first weights); "
        "torch rows run the model's forward for that material.",
        "rows": rows,
    }
