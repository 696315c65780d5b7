"""Executors: how a job runs its shards in parallel.

A job kind never picks a backend; it calls ``ctx.map_shards(fn, items)`` and the context
hands the work to an :class:`Executor`. This module is the interface and the in-process
backend, :class:`InlineExecutor` (tests, tiny jobs); the worker's backends (a pool of
spawned processes, or Ray tasks on a cluster) live at the edge, in
:mod:`service.workers.executors`, and implement :meth:`Executor.start`,
:meth:`Executor.map`, :meth:`Executor.describe` and :meth:`Executor.close`. No job kind
changes when a backend is added, and every backend gives the same results for the same
items.

Shard functions must be module-level functions (picklable), take one item and return a
picklable result.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol


class Executor(Protocol):
    """Runs ``fn(item)`` for each item; yields ``(index, result)`` in completion order."""

    name: str

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]: ...

    def start(self) -> None:
        """Acquire what the backend needs before a job is claimed (join a cluster); raises
        :class:`~jobapi.errors.ExecutorUnavailable` when it cannot."""
        ...

    def describe(self) -> dict[str, Any]:
        """Where shards ran, for the job's manifest: ``{"executor": name, "executor_nodes":
        machines}`` (``process``: 1; ``ray``: the cluster's live nodes)."""
        ...

    def close(self) -> None: ...

    # Optional: ``abort()``, callable from another thread, makes a blocked ``map`` raise at
    # once (kill the shard processes, cancel the tasks). The worker calls it when a job is
    # cancelled, stuck or out of time; a backend without it is waited for, then its worker
    # ended.


class InlineExecutor:
    """Runs shards one after another in the calling process."""

    name = "inline"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        for i, item in enumerate(items):
            yield i, fn(item)

    def start(self) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return {"executor": self.name, "executor_nodes": 1}

    def close(self) -> None:
        pass
