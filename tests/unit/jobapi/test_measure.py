"""``JobContext.measure``: what a kind times itself reaches the manifest, checked on entry;
``kernel_compile_timer`` sees Dr.Jit's own compile times (the reference: Dr.Jit's kernel
history, with a kernel that is not in its cache)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from jobapi.context import JobContext
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore


def _ctx(tmp_path: Path) -> JobContext:
    return JobContext(
        job_id="0" * 32,
        seed=0,
        spec={},
        store=ArtifactStore(tmp_path / "objects"),
        jobs=JobStore(tmp_path / "jobs.db"),
        workdir=tmp_path,
    )


def test01_measure_keeps_finite_times(tmp_path: Path) -> None:
    ctx = _ctx(tmp_path)
    ctx.measure("render_seconds", 1.25)
    assert ctx.measured == {"render_seconds": 1.25}
    for name, value in (("Render", 1.0), ("x" * 65, 1.0), ("ok", -1.0), ("ok", math.nan)):
        with pytest.raises(ValueError):
            ctx.measure(name, value)


def test02_compile_timer_counts_a_new_kernel() -> None:
    import drjit as dr

    from evaluators.render.kind import kernel_compile_timer
    from materials.backend import load_mitsuba

    load_mitsuba()
    before = dr.flag(dr.JitFlag.KernelHistory)
    with kernel_compile_timer() as t:
        # a kernel whose literal (the clock) makes it new to Dr.Jit's kernel cache
        x = dr.arange(dr.llvm.Float, 1000) * float(time.time_ns() % 10**9 + 0.5)
        dr.eval(dr.sin(x) + dr.cos(x * x))
    assert 0 < t.seconds < 60
    assert dr.flag(dr.JitFlag.KernelHistory) == before  # the flag is restored
