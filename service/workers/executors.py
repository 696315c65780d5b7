"""The worker's executor backends: a pool of spawned processes, or inline.

See :mod:`jobapi.executor` for the interface a backend implements. Shard functions must be
module-level functions (picklable), take one item and return a picklable result.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from jobapi.executor import Executor, InlineExecutor


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
