"""The memory limit of job processes: the setting, its share of the machine, what counts as
running out of memory, and the kernel limit itself (in a child process)."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

import service.settings as settings_module
from service.settings import Settings
from service.workers.execution import crash_message
from service.workers.memory import death_message, is_out_of_memory

GIB = 1 << 30


def test_setting_parses_auto_zero_and_mib() -> None:
    assert Settings.from_env({}).job_memory_bytes is None
    assert Settings.from_env({"MATFORGE_JOB_MEMORY_MB": "auto"}).job_memory_bytes is None
    assert Settings.from_env({"MATFORGE_JOB_MEMORY_MB": "0"}).job_memory_limit() is None
    s = Settings.from_env({"MATFORGE_JOB_MEMORY_MB": "1536"})
    assert s.job_memory_limit() == 1536 << 20
    assert Settings.from_env(s.to_env()).job_memory_bytes == 1536 << 20
    assert Settings.from_env(Settings().to_env()).job_memory_bytes is None
    with pytest.raises(ValueError, match="MATFORGE_JOB_MEMORY_MB"):
        Settings.from_env({"MATFORGE_JOB_MEMORY_MB": "lots"})
    with pytest.raises(ValueError, match="MATFORGE_JOB_MEMORY_MB"):
        Settings.from_env({"MATFORGE_JOB_MEMORY_MB": "-1"})


def test_auto_limit_is_a_share_of_the_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(settings_module, "physical_memory", lambda: 24 * GIB)
    # three quarters of 24 GiB over one worker and its two shard processes
    assert Settings(workers=1, pool_processes=2).job_memory_limit() == 6 * GIB
    assert Settings(workers=2, pool_processes=2).job_memory_limit() == 3 * GIB
    # never below 1 GiB: a worker with Mitsuba and torch loaded needs about half of that
    assert Settings(workers=8, pool_processes=2).job_memory_limit() == GIB
    monkeypatch.setattr(settings_module, "physical_memory", lambda: None)
    assert Settings().job_memory_limit() is None


class _OrtFail(Exception):
    """Stands for onnxruntime's ``Fail`` (its module is what is matched)."""


_OrtFail.__module__ = "onnxruntime.capi.onnxruntime_pybind11_state"

TORCH = (
    "[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: can't allocate "
    "memory: you tried to allocate 1073741824 bytes. Error code 12 (Cannot allocate memory)"
)
ORT = (
    "[ONNXRuntimeError] : 1 : FAIL : Non-zero status code returned while running Add node. "
    "BFCArena::AllocateRawInternal Failed to allocate memory for requested buffer of size "
    "4294967296"
)


def test_runtimes_allocation_failures_are_out_of_memory() -> None:
    assert is_out_of_memory(MemoryError())
    assert is_out_of_memory(RuntimeError(TORCH))
    assert is_out_of_memory(_OrtFail(ORT))
    assert is_out_of_memory(OSError(12, "Cannot allocate memory"))
    try:
        try:
            raise MemoryError
        except MemoryError as inner:
            raise ValueError("I/O operation on closed file") from inner
    except ValueError as outer:
        assert is_out_of_memory(outer)
    assert not is_out_of_memory(RuntimeError("index 3 is out of bounds"))
    assert not is_out_of_memory(_OrtFail("[ONNXRuntimeError] : 2 : INVALID_ARGUMENT"))
    assert not is_out_of_memory(ValueError("can't allocate memory"))  # not a runtime's error


def test_crash_messages_start_out_of_memory() -> None:
    msg = crash_message("render", _OrtFail(ORT), "bounce 1")
    assert msg.startswith("out of memory in render (bounce 1): "), msg
    assert crash_message("render", RuntimeError("boom"), None).startswith("internal error")
    died = death_message("render", "pass 1/8", signal.SIGSEGV, 1536 << 20)
    assert died.startswith("out of memory in render (pass 1/8): "), died
    assert "SIGSEGV" in died and "1536 MiB" in died and "MATFORGE_JOB_MEMORY_MB" in died


def test_kernel_limit_refuses_an_allocation_past_it() -> None:
    """In a child: under a 256 MiB limit, asking numpy for 1 GiB (untouched, which without
    the limit is granted) raises MemoryError; 64 MiB is still granted."""
    code = (
        "from service.workers.memory import limit_memory, current_limit; import numpy as np\n"
        "limit_memory(256 << 20); assert current_limit() == 256 << 20\n"
        "np.empty(64 << 20, np.uint8)\n"
        "try:\n    np.empty(1 << 30, np.uint8)\nexcept MemoryError:\n    print('refused')\n"
        "else:\n    print('granted')\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.strip() == "refused", out


def test_a_kinds_failure_that_wraps_a_failed_allocation_is_out_of_memory() -> None:
    """Mitsuba reports a plugin's exception as text, which the render kind names as its
    failure: onnxruntime's ``std::bad_alloc`` while its session starts (an ONNX model whose
    constants fold to 1 GiB) reached the job as "material.external: At dictionary node
    ...: Traceback ..." before."""
    from jobapi.errors import JobFailed
    from service.workers.execution import failure_message

    wrapped = JobFailed(
        'material.external: At dictionary node "root": failed to instantiate unknown plugin '
        'of type "external_onnx": Traceback (most recent call last): File "x.py", line 1 '
        "onnxruntime.capi.onnxruntime_pybind11_state.RuntimeException: [ONNXRuntimeError] : "
        "6 : RUNTIME_EXCEPTION : Exception during initialization: std::bad_alloc"
    )
    msg = failure_message("render", wrapped, "starting Mitsuba")
    assert msg.startswith("out of memory in render (starting Mitsuba): "), msg
    assert msg.endswith(
        '(material.external: At dictionary node "root": failed to instantiate '
        'unknown plugin of type "external_onnx")'
    ), msg
    plain = JobFailed("material.external.model: sha256:ab: not an ONNX model")
    assert failure_message("render", plain, None) == str(plain)
