"""Where jobs run: worker processes and their supervisor, one job's execution, executors.

Submodules: :mod:`~service.workers.worker` (worker loop and :class:`Supervisor`),
:mod:`~service.workers.execution` (one claimed job: heartbeats, runner, manifest, fenced
completion), :mod:`~service.workers.executors` (the shard backends behind
:mod:`jobapi.executor`), :mod:`~service.workers.liveness` (worker beats and the parent
watch) and :mod:`~service.workers.provenance` (code and package versions).
"""

SUBMODULES: tuple[str, ...] = ("provenance", "executors", "execution", "liveness", "worker")
