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

A backend whose shards all run where the job's artifact store is mounted at the same path
(``MATFORGE_SHARED_STORE``: one machine, or a POSIX file system every node mounts, such as
NFS or Lustre) says so with ``shared_store = True``. Then
:meth:`jobapi.context.JobContext.map_artifact_shards` hands it :class:`StoreShard`, which
writes each shard's bytes into the store inside the shard task (the store's own atomic
temp-file, fsync, rename protocol) and returns only their :class:`~storage.artifacts.
ObjectInfo`: the job's thread records digests instead of writing every shard itself.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from storage.artifacts import ArtifactStore, ObjectInfo
from storage.errors import NotFoundError


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

    # Optional: ``shared_store: bool`` (see the module's docstring; absent means False).
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


def uses_shared_store(executor: Executor) -> bool:
    """Whether ``executor``'s shards may write into the job's store themselves: its
    ``shared_store`` attribute, an explicit setting (``MATFORGE_SHARED_STORE``), never a
    guess from the file system."""
    return getattr(executor, "shared_store", False) is True


@dataclass(frozen=True)
class StoreShard:
    """A shard function that stores its own result: ``fn(item)`` (bytes) is written into
    the artifact store at ``root`` where the shard runs, and only its digest and size go
    back to the job. ``root`` is absolute: a shard task on another node has another
    working directory. Picklable when ``fn`` is a module-level function."""

    fn: Callable[[Any], bytes]
    root: str

    def __call__(self, item: Any) -> ObjectInfo:
        data = self.fn(item)
        if not isinstance(data, bytes | bytearray | memoryview):
            raise TypeError(
                f"shard function {getattr(self.fn, '__name__', self.fn)!r} returned "
                f"{type(data).__name__}, not bytes"
            )
        try:
            store = ArtifactStore(self.root, create=False)
        except NotFoundError as exc:
            raise NotFoundError(
                f"{exc} ({socket.gethostname()}): with MATFORGE_SHARED_STORE=1 every node "
                "must mount the store at that path"
            ) from None
        return store.put_bytes(bytes(data))
