"""One timing pass: every model of a comparison timed in one process, interleaved, beside a
reference kernel (``matforge.timing/1``).

A cost taken in one job and a cost taken in another are not comparable on a shared machine
(the same fused 32x3 model measured 30.9 and 139.1 ns per evaluation ten minutes apart, in
two jobs). A comparison (``report.pareto``, ``select``) therefore times every model it ranks
in one pass (:func:`timing_pass`), the way asv interleaves its runs and
``torch.utils.benchmark`` reports a distribution:

- one process, the same batch of queries for every kernel (built by the caller, once);
- ``warmup`` rounds first (JIT compilation, caches, thread pools), not recorded;
- then ``repeats`` rounds; each round runs every kernel once, round-robin, the starting
  kernel rotating by one each round, so no kernel always follows the same neighbour;
- before each clock read the kernel's runtime is synchronised (:attr:`Kernel.sync`: Dr.Jit
  is lazy and asynchronous, ``dr.eval`` then ``dr.sync_thread()``; torch on CUDA
  ``torch.cuda.synchronize()``), so the time between two reads is the kernel's whole work;
- threads fixed for the pass (:func:`fixed_threads`: Dr.Jit's pool and torch's) and recorded.

The clock: on a CPU, the process CPU time of all threads divided by the thread count (the
time on that many dedicated cores), as :func:`models.speed.time_cpu` measures it; on a
shared machine a call's wall time grows with the other processes' load, and grows more the
longer the call (a short kernel often finishes inside one scheduler slice, a long one waits
through many), so wall ratios between a short and a long kernel drift with the load where
CPU-time ratios do not. On a GPU the clock is the wall time. Every call's wall time is
recorded beside it (``wall``).

Each kernel's cost is a distribution over its repeats (:func:`distribution`: median, min,
max, quartiles, IQR, n), in ns per evaluation. One kernel is the *reference* (for a BRDF,
Mitsuba's native ``roughconductor`` evaluated on the same batch,
:mod:`models.timing_kernels`); every other kernel's cost is also given relative to it:
per round, the kernel's time over the reference's time in that same round, then the
distribution of those ratios. Load that changes during the pass slows both members of a
round alike, so the ratio holds where the absolute time does not.

The record (:func:`timing_pass`'s return value) names the machine beside the numbers
(:func:`machine`: CPU model, cores, threads, load average before and after, runtimes and the
Mitsuba variant). Its ``costs`` entries have the cost-record shape every cost of a model
takes: ``ns_per_eval`` (the median) with its distribution and ``relative``, ``runtime``,
and the optional counts ``macs_per_eval`` and ``bytes_per_eval`` (multiply-adds and bytes
read per evaluation) when the kernel states them. Timings vary from run to run.
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

#: The version tag of a timing record.
TIMING_FORMAT = "matforge.timing/1"
#: The clocks a pass may time with, and what they measure.
CLOCKS = {
    "wall": "wall time",
    "cpu": "process CPU time over all threads / threads (the time on that many dedicated cores)",
}
#: Recorded rounds per kernel, at least (the spec setting's default and minimum).
MIN_REPEATS = 5
#: Calls per sample at most (see ``min_sample_s``).
MAX_CALLS = 1000
#: Unrecorded rounds before them (a frozen Dr.Jit kernel records on its first call and
#: replays from its second).
WARMUP = 2


def no_sync(_out: Any) -> None:
    """The synchronisation of a runtime whose calls return finished results (numpy,
    onnxruntime on the CPU, torch on the CPU)."""


@dataclass(frozen=True)
class Kernel:
    """One thing to time: ``run()`` evaluates the whole batch once and returns its outputs;
    ``sync(outputs)`` waits until they exist (called after ``run`` and, with ``None``,
    before the start clock read, so no earlier work is charged to the kernel)."""

    name: str
    """Its name in the record (a candidate's label, or ``reference``)."""
    run: Callable[[], Any]
    """One evaluation of the batch."""
    evals: int
    """Evaluations per ``run()`` (the batch size)."""
    runtime: str
    """What evaluates it: ``drjit-fused``, ``onnxruntime``, ``mitsuba``, ``torch`` ..."""
    sync: Callable[[Any], None] = no_sync
    """Waits for ``run()``'s outputs (see the class docstring)."""
    counts: dict[str, float] = field(default_factory=dict)
    """Optional machine-independent counts: ``macs_per_eval``, ``bytes_per_eval``."""


def distribution(values: Sequence[float]) -> dict[str, float | int]:
    """``{"median", "min", "max", "q1", "q3", "iqr", "n"}`` of repeated measurements;
    quartiles by :func:`statistics.quantiles` (``method="inclusive"``: within min..max)."""
    if not values:
        raise ValueError("no values")
    vals = [float(v) for v in values]
    if len(vals) > 1:
        q1, _, q3 = statistics.quantiles(vals, n=4, method="inclusive")
    else:
        q1 = q3 = vals[0]
    return {
        "median": statistics.median(vals),
        "min": min(vals),
        "max": max(vals),
        "q1": q1,
        "q3": q3,
        "iqr": q3 - q1,
        "n": len(vals),
    }


def round_order(n: int, round_index: int) -> list[int]:
    """The kernels' order in round ``round_index``: ``0 .. n-1`` rotated by the round."""
    s = round_index % n if n else 0
    return [*range(s, n), *range(s)]


def _load() -> list[float]:
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    return [round(v, 2) for v in load]


def cpu_name() -> str:
    """The CPU model (``/proc/cpuinfo``'s ``model name``), else the platform's word."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine(threads: int, runtimes: dict[str, str] | None = None) -> dict[str, Any]:
    """Where a pass runs: CPU model, cores, the pass's threads, the load average now (1, 5
    and 15 minutes), the Python version and ``runtimes`` (name -> version or variant)."""
    return {
        "processor": cpu_name(),
        "machine": platform.machine(),
        "cores": os.cpu_count(),
        "threads": threads,
        "load_before": _load(),
        "python": platform.python_version(),
        "runtimes": dict(runtimes or {}),
    }


@contextmanager
def fixed_threads(threads: int) -> Iterator[None]:
    """Dr.Jit's and torch's thread counts set to ``threads`` for the block (restored after);
    a runtime that is not installed is left alone."""
    undo: list[Callable[[], None]] = []
    try:
        try:
            import drjit as dr

            old_dr = dr.thread_count()
            dr.set_thread_count(threads)
            undo.append(lambda: dr.set_thread_count(old_dr))
        except ImportError:  # pragma: no cover - Dr.Jit is a dependency
            pass
        try:
            import torch

            old_torch = torch.get_num_threads()
            torch.set_num_threads(threads)
            undo.append(lambda: torch.set_num_threads(old_torch))
        except ImportError:  # pragma: no cover - torch is a dependency
            pass
        yield
    finally:
        for fn in reversed(undo):
            fn()


def timing_pass(
    kernels: Sequence[Kernel],
    *,
    reference: str | None = None,
    repeats: int = MIN_REPEATS,
    warmup: int = WARMUP,
    threads: int | None = None,
    clock: Callable[[], float] = time.perf_counter,
    clock_name: str = "wall",
    per: int = 1,
    min_sample_s: float = 0.0,
    runtimes: dict[str, str] | None = None,
    settings: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Time ``kernels`` in one interleaved pass (see the module docstring) and return the
    ``matforge.timing/1`` record.

    ``reference`` names the reference kernel (one of ``kernels``); ``threads`` is recorded
    (set it with :func:`fixed_threads` around the call); ``clock`` returns seconds
    (injectable for tests), named ``clock_name`` in the record (:data:`CLOCKS`), and each
    reading is divided by ``per`` (the thread count, for the process CPU clock: then a cost
    is the time on that many dedicated cores). The wall time of every call is recorded
    beside it (``wall``). ``min_sample_s``: after the warm-up, each kernel's sample is
    that many back-to-back calls (each synchronised) that take at least this long by the
    last warm-up round's time (``calls``, as ``torch.utils.benchmark``'s
    ``blocked_autorange`` sizes its blocks), so that a short kernel is not measured at the
    clock's and the thread pool's granularity; 0: one call. ``settings`` (batch, seed, ...)
    is recorded as given.
    Raises ``ValueError`` for fewer than :data:`MIN_REPEATS` repeats, duplicate names, or
    a ``reference`` that is not among the kernels.
    """
    if repeats < MIN_REPEATS:
        raise ValueError(f"repeats: at least {MIN_REPEATS}, got {repeats}")
    if warmup < 0:
        raise ValueError(f"warmup: at least 0, got {warmup}")
    names = [k.name for k in kernels]
    if len(set(names)) != len(names):
        raise ValueError(f"kernel names repeat: {sorted({n for n in names if names.count(n) > 1})}")
    if reference is not None and reference not in names:
        raise ValueError(f"reference {reference!r} is not one of the kernels {names}")
    env = machine(threads if threads is not None else 0, runtimes)
    if per < 1:
        raise ValueError(f"per: at least 1, got {per}")
    seconds: dict[str, list[float]] = {k.name: [] for k in kernels}
    walls: dict[str, list[float]] = {k.name: [] for k in kernels}
    calls = {k.name: 1 for k in kernels}
    order: list[list[str]] = []
    for rnd in range(warmup + repeats):
        this = [kernels[i] for i in round_order(len(kernels), rnd)]
        if rnd >= warmup:
            order.append([k.name for k in this])
        for k in this:
            k.sync(None)
            wall = time.perf_counter()
            start = clock()
            for _ in range(calls[k.name]):
                out = k.run()
                k.sync(out)
                del out
            stop = clock()
            wall = time.perf_counter() - wall
            if rnd >= warmup:
                seconds[k.name].append((stop - start) / per / calls[k.name])
                walls[k.name].append(wall / calls[k.name])
            elif rnd == warmup - 1 and min_sample_s > 0:  # size the samples
                took = (stop - start) / per
                calls[k.name] = max(1, min(MAX_CALLS, math.ceil(min_sample_s / max(took, 1e-9))))
    env["load_after"] = _load()
    costs: dict[str, dict[str, Any]] = {}
    ref = seconds.get(reference) if reference is not None else None
    ref_evals = next((k.evals for k in kernels if k.name == reference), 1)
    for k in kernels:
        ns = [s / k.evals * 1e9 for s in seconds[k.name]]
        dist = distribution(ns)
        entry: dict[str, Any] = {
            "ns_per_eval": dist["median"],
            "distribution": dist,
            "wall": distribution([s / k.evals * 1e9 for s in walls[k.name]]),
            "runtime": k.runtime,
            "evals": k.evals,
            "calls": calls[k.name],
            "macs_per_eval": k.counts.get("macs_per_eval"),
            "bytes_per_eval": k.counts.get("bytes_per_eval"),
        }
        if ref is not None:
            ratios = [
                (s / k.evals) / (r / ref_evals)
                for s, r in zip(seconds[k.name], ref, strict=True)
                if r > 0
            ]
            entry["relative"] = distribution(ratios) if ratios else None
        costs[k.name] = entry
    return {
        "format": TIMING_FORMAT,
        "reference": reference,
        "repeats": repeats,
        "warmup": warmup,
        "clock": clock_name,
        "order": order,
        "machine": env,
        "settings": dict(settings or {}),
        "costs": costs,
        "method": f"{CLOCKS.get(clock_name, clock_name)} per kernel call (run, then its "
        "runtime synchronised) in interleaved rounds, the first kernel rotating each round; "
        "ns_per_eval = time / evaluations; relative = per round, the kernel's ns_per_eval "
        "over the reference's; wall: the calls' wall time",
    }
