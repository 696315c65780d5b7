"""Executors: how a job runs its shards in parallel.

A job kind never picks a backend; it calls ``ctx.map_shards(fn, items)`` and the context
hands the work to an :class:`Executor`. The default is :class:`LocalPoolExecutor`, a pool of
spawned processes; :class:`InlineExecutor` runs in the calling process (tests, tiny jobs).
A Ray backend only has to implement :meth:`Executor.map` and :meth:`Executor.close`
(``ray.remote(fn).remote(item)`` per item, ``ray.wait`` for completion order) and be added
to :func:`make_executor`; no job kind changes.

Shard functions must be module-level functions (picklable), take one item and return a
picklable result.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any, Protocol


class Executor(Protocol):
    """Runs ``fn(item)`` for each item; yields ``(index, result)`` in completion order."""

    name: str

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]: ...

    def close(self) -> None: ...


class InlineExecutor:
    """Runs shards one after another in the calling process."""

    name = "inline"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        for i, item in enumerate(items):
            yield i, fn(item)

    def close(self) -> None:
        pass


class LocalPoolExecutor:
    """A pool of ``processes`` spawned worker processes, created lazily and reused.

    ``spawn`` (not ``fork``) because Dr.Jit and torch start threads that do not survive a
    fork. At most ``2 * processes`` shards are in flight, so a cancelled job stops quickly.
    """

    name = "local"

    def __init__(self, processes: int = 2) -> None:
        self.processes = max(1, processes)
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.processes, mp_context=mp.get_context("spawn")
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
        finally:
            for fut in pending:
                fut.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def make_executor(name: str = "local", processes: int = 2) -> Executor:
    """The executor backend called ``name`` (``"local"`` or ``"inline"``)."""
    if name == "local":
        return LocalPoolExecutor(processes)
    if name == "inline":
        return InlineExecutor()
    raise ValueError(f"unknown executor backend {name!r}; known: local, inline")
