"""Executors: how a job runs its shards in parallel.

A job kind never picks a backend; it calls ``ctx.map_shards(fn, items)`` and the context
hands the work to an :class:`Executor`. This module is the interface and the in-process
backend, :class:`InlineExecutor` (tests, tiny jobs); the worker's backends (a pool of
spawned processes; Ray would be another) live at the edge, in
:mod:`service.workers.executors`, and implement :meth:`Executor.map` and
:meth:`Executor.close`. No job kind changes when a backend is added.

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

    def close(self) -> None: ...


class InlineExecutor:
    """Runs shards one after another in the calling process."""

    name = "inline"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        for i, item in enumerate(items):
            yield i, fn(item)

    def close(self) -> None:
        pass
