"""The memory limit of the processes that run jobs, and what running out of it is called.

A worker of ``matforge serve`` caps its own memory before it loads Mitsuba
(:func:`limit_memory`, ``MATFORGE_JOB_MEMORY_MB``,
:meth:`~service.settings.Settings.job_memory_limit`); its shard processes inherit the cap,
each its own. The kernel enforces
it with ``RLIMIT_DATA``, which counts the heap and private writable mappings, what a process
can actually fill, and not ``RLIMIT_AS``: Dr.Jit's LLVM JIT, torch and onnxruntime reserve
address space far beyond what they use, and an address-space cap refuses them long before
memory runs short (``benchmarks/bench_memory_limits.py``: with 16 threads per runtime the
same work holds 2.5 GiB of address space for 0.5 GiB of memory, and an address-space cap of
1.5 GiB aborts it). An allocation past the cap fails at once, before any page is touched, so
one job cannot take the machine's memory and leave the OOM killer to pick a victim.

How a job meets the cap depends on the runtime, and all of it is reported as an error that
starts ``out of memory`` (:func:`is_out_of_memory`, :func:`death_message`):

- Python and numpy raise ``MemoryError``;
- torch raises ``RuntimeError: ... DefaultCPUAllocator: can't allocate memory``;
- onnxruntime raises its ``Fail`` with ``Failed to allocate memory``;
- C++ code that does not catch ``std::bad_alloc`` aborts the process (SIGABRT), and Dr.Jit
  ends it with SIGSEGV: the supervisor sees its worker die of that signal while it ran a job
  (:meth:`service.workers.worker.Supervisor.check`), fails the job, and starts another
  worker. A shard process that dies so breaks the job's pool
  (:func:`service.workers.execution.crash_message`).

After a job ran out of memory its worker exits and the supervisor starts a fresh one, so
the next job never runs in a process whose heap a failed job left fragmented.
"""

from __future__ import annotations

import re
import resource
import signal

#: Signals a job's process dies of when an allocation past its limit fails in native code:
#: an uncaught ``std::bad_alloc`` aborts; Dr.Jit dereferences the failed allocation.
NATIVE_OOM_SIGNALS = frozenset({signal.SIGSEGV, signal.SIGABRT, signal.SIGBUS})

#: The messages of the runtimes' allocation failures (torch, onnxruntime, C++, Dr.Jit).
_ALLOCATION_FAILED = re.compile(
    r"can't allocate memory|failed to allocate memory|bad_alloc|cannot allocate memory|"
    r"out of memory",
    re.IGNORECASE,
)


#: What a kind's own failure message holds when it wraps a failed allocation (Mitsuba
#: reports a plugin's exception as a RuntimeError with its traceback as text, which a kind
#: then names as its failure): the runtimes' words, or Python's ``MemoryError``.
_WRAPPED_ALLOCATION_FAILED = re.compile(
    r"can't allocate memory|failed to allocate memory|bad_alloc|cannot allocate memory|"
    r"\bMemoryError\b",
    re.IGNORECASE,
)


def limit_memory(max_bytes: int) -> int:
    """Cap this process's data segment (heap and private writable mappings) at
    ``max_bytes``, or at the hard limit already set if that is lower; returns the cap in
    force. Children started afterwards inherit it."""
    _, hard = resource.getrlimit(resource.RLIMIT_DATA)
    cap = max_bytes if hard == resource.RLIM_INFINITY else min(max_bytes, hard)
    resource.setrlimit(resource.RLIMIT_DATA, (cap, hard if hard != resource.RLIM_INFINITY else cap))
    return cap


def current_limit() -> int | None:
    """This process's ``RLIMIT_DATA`` soft limit in bytes, or ``None`` when unlimited."""
    soft, _ = resource.getrlimit(resource.RLIMIT_DATA)
    return None if soft == resource.RLIM_INFINITY else int(soft)


def exception_chain(exc: BaseException) -> list[BaseException]:
    """``exc`` and its causes and contexts, outermost first (each once)."""
    seen: list[BaseException] = []
    cur: BaseException | None = exc
    while cur is not None and all(cur is not e for e in seen):
        seen.append(cur)
        cur = cur.__cause__ or cur.__context__
    return seen


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` (or an exception it came from) is a failed allocation: a
    ``MemoryError``, or a runtime's error saying so (see the module docstring)."""
    for e in exception_chain(exc):
        if isinstance(e, MemoryError):
            return True
        if isinstance(e, RuntimeError | OSError) or type(e).__module__.startswith("onnxruntime"):
            if _ALLOCATION_FAILED.search(str(e)):
                return True
    return False


def mentions_allocation_failure(message: str) -> bool:
    """Whether a kind's failure message wraps a failed allocation (see
    :data:`_WRAPPED_ALLOCATION_FAILED`)."""
    return _WRAPPED_ALLOCATION_FAILED.search(message) is not None


def describe_limit(limit: int | None) -> str:
    """``"its memory limit of 4096 MiB (MATFORGE_JOB_MEMORY_MB)"``, or ``"the machine's
    memory (no limit set)"``."""
    if limit is None:
        return "the machine's memory (no limit set)"
    return f"its memory limit of {limit >> 20} MiB (MATFORGE_JOB_MEMORY_MB)"


def death_message(kind: str, step: str | None, signum: int, limit: int | None) -> str:
    """The ``error`` of a job whose worker process died of signal ``signum`` while it ran
    the job (one of :data:`NATIVE_OOM_SIGNALS`)."""
    at = f" ({step})" if step else ""
    try:
        name = signal.Signals(signum).name
    except ValueError:
        name = f"signal {signum}"
    return (
        f"out of memory in {kind}{at}: the worker process died of {name} while running it, "
        f"as native code does when an allocation past {describe_limit(limit)} fails (or it "
        "crashed); use smaller inputs or shards, or raise the limit. The job was not retried"
    )
