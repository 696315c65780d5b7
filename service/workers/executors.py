"""The worker's executor backends: a pool of spawned processes, Ray tasks, or inline.

See :mod:`jobapi.executor` for the interface a backend implements. Shard functions must be
module-level functions (picklable), take one item and return a picklable result.
:func:`executor_for` picks the backend that ``MATFORGE_EXECUTOR`` names
(:class:`~service.settings.Settings`); Ray is imported only when it is chosen
(:mod:`service.workers.ray_executor`).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from jobapi.errors import ExecutorUnavailable
from jobapi.executor import Executor, InlineExecutor
from service.settings import Settings

#: A shard process's initialiser and its arguments.
Setup = tuple[Callable[..., None], tuple[Any, ...]]


class LocalPoolExecutor:
    """A pool of ``processes`` spawned worker processes, created lazily and reused.

    ``spawn`` (not ``fork``) because Dr.Jit and torch start threads that do not survive a
    fork. ``setup`` (``(initializer, args)``) runs once in each new process: the Mitsuba
    variant of the job's process (:func:`service.workers.backend.setup_shard_process`).
    At most ``2 * processes`` shards are in flight, so a cancelled job stops quickly.
    ``shared_store``: the shard processes store their own results
    (``MATFORGE_SHARED_STORE``, :mod:`jobapi.executor`); on one machine they always can.
    """

    name = "process"

    def __init__(
        self, processes: int = 2, setup: Setup | None = None, *, shared_store: bool = False
    ) -> None:
        self.processes = max(1, processes)
        self.setup = setup
        self.shared_store = shared_store
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            init, args = self.setup if self.setup is not None else (None, ())
            self._pool = ProcessPoolExecutor(
                max_workers=self.processes,
                mp_context=mp.get_context("spawn"),
                initializer=init,
                initargs=args,
            )
        return self._pool

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        if len(items) <= 1 or self.processes == 1:
            yield from InlineExecutor().map(fn, items)
            return
        pool = self._get_pool()
        pending: dict[Future[Any], int] = {}
        next_i = 0
        try:
            while next_i < len(items) or pending:
                while next_i < len(items) and len(pending) < 2 * self.processes:
                    pending[pool.submit(fn, items[next_i])] = next_i
                    next_i += 1
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = pending.pop(fut)
                    yield i, fut.result()
        except BrokenProcessPool:
            self._discard(pool)  # a process died or was killed (abort): the next map starts anew
            raise
        finally:
            for fut in pending:
                fut.cancel()

    def abort(self) -> None:
        """Kill the pool's processes, from any thread: a map blocked on them (stopped by
        SIGSTOP, hung) raises ``BrokenProcessPool`` at once, and the next map starts a
        fresh pool. The heartbeat calls it when a job is cancelled, stuck or timed out."""
        pool = self._pool
        if pool is None:
            return
        for proc in list(getattr(pool, "_processes", {}).values()):
            try:
                proc.kill()  # SIGKILL ends a stopped process too
            except (OSError, ValueError):
                pass

    def _discard(self, pool: ProcessPoolExecutor) -> None:
        if self._pool is pool:
            self._pool = None
        pool.shutdown(wait=False, cancel_futures=True)

    def start(self) -> None:
        pass  # the pool starts with the first map of more than one shard

    def describe(self) -> dict[str, Any]:
        return {"executor": self.name, "executor_nodes": 1}

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def make_executor(
    name: str = "process",
    processes: int = 2,
    *,
    ray_address: str | None = None,
    ray_max_retries: int = 3,
    ray_auth_mode: str | None = None,
    setup: Setup | None = None,
    shared_store: bool = False,
) -> Executor:
    """The executor backend called ``name``: ``"process"`` (alias ``"local"``), ``"ray"``
    or ``"inline"``. ``processes`` is the pool's size, or the CPUs of a private local Ray
    when ``ray_address`` is unset; ``setup`` initialises each shard process;
    ``shared_store``: the shards store their own results (``MATFORGE_SHARED_STORE``)."""
    if name in ("process", "local"):
        return LocalPoolExecutor(processes, setup, shared_store=shared_store)
    if name == "ray":
        try:
            from service.workers.ray_executor import RayExecutor
        except ImportError as exc:
            raise ExecutorUnavailable(
                f"MATFORGE_EXECUTOR=ray but Ray is not installed: {exc}"
            ) from None
        return RayExecutor(
            ray_address,
            num_cpus=processes,
            max_retries=ray_max_retries,
            auth_mode=ray_auth_mode,
            setup=setup,
            shared_store=shared_store,
        )
    if name == "inline":
        return InlineExecutor()
    raise ValueError(f"unknown executor backend {name!r}; known: process, ray, inline")


def executor_for(settings: Settings) -> Executor:
    """The backend that ``settings`` name (``MATFORGE_EXECUTOR``, ``RAY_ADDRESS``,
    ``MATFORGE_SHARED_STORE``); its shard processes take ``settings.variant`` (resolve it
    first: :func:`~service.workers.backend.start_backend`)."""
    from service.workers.backend import setup_shard_process

    return make_executor(
        settings.executor,
        settings.pool_processes,
        ray_address=settings.ray_address,
        ray_max_retries=settings.ray_max_retries,
        ray_auth_mode=settings.ray_auth_mode,
        setup=(setup_shard_process, (settings.variant, settings.libllvm_path)),
        shared_store=settings.shared_store,
    )
