"""The Ray backend of :mod:`jobapi.executor`: each shard is a Ray task.

``MATFORGE_EXECUTOR=ray`` selects it (:mod:`service.settings`). The job itself stays in the
worker process: the context hands ``fn`` and the shard items to :meth:`RayExecutor.map`,
Ray runs ``fn(item)`` on some node of the cluster, and the result comes back to the job,
which writes it into the artifact store and records the finished shard exactly as with the
local pool. Where every node mounts the store (``MATFORGE_SHARED_STORE=1``) the task writes
an artifact shard into the store itself and only its digest and size come back
(:class:`jobapi.executor.StoreShard`). So resumption, cancellation and the bytes of every
artifact do not depend on the backend; only where the arithmetic runs (and, with a shared
store, where the bytes are written) does.

- Items are what the kinds already hand the pool: small parameter records, seeds and paths,
  never the data set's arrays (a shard *returns* its bytes).
- A shard whose node dies, or whose worker process crashes, is a system failure: Ray runs it
  again, at most ``max_retries`` times. A shard that raises one of
  :data:`jobapi.errors.TRANSIENT_ERRORS` is retried the same way (``retry_exceptions``);
  any other exception is the shard's own and reaches the job unchanged, as it would from
  the local pool.
- At most ``2 x`` the cluster's CPUs are in flight, so a cancelled job stops quickly and the
  object store holds a bounded number of results.

Security: Ray's Jobs API and dashboard have no auth by default (CVE-2023-48022). matforge
never starts them (``include_dashboard=False``) and connects to a cluster as a plain driver
over Ray's GCS port; run the cluster with ``RAY_AUTH_MODE=token`` (Ray >= 2.52), see
``docs/ray.md``.
"""

from __future__ import annotations

import logging
import pickle
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import ray
from ray.exceptions import RayError, RayTaskError

from jobapi.errors import TRANSIENT_ERRORS, ExecutorUnavailable, ShardLost

log = logging.getLogger("matforge.ray")
#: A shard process's initialiser and its arguments.
Setup = tuple[Callable[..., None], tuple[Any, ...]]

#: Object store of a private local Ray (bytes): shards' results are fetched as they finish,
#: so a few hundred megabytes suffice, and /dev/shm is shared with the rest of the machine.
LOCAL_OBJECT_STORE_BYTES = 512 * 1024 * 1024


def run_shard(fn: Callable[[Any], Any], item: bytes, setup: Setup | None = None) -> bytes:
    """The body of every Ray task: the kind's own shard function on one pickled item, its
    result pickled. ``setup`` is ``(initializer, args)``, run first (the Mitsuba variant the
    job's process resolved, :func:`service.workers.backend.setup_shard_process`; cheap and
    idempotent, as a Ray worker process runs many tasks).

    Item and result travel as pickles, as through the local pool, rather than through Ray's
    own serialiser: that one hands numpy arrays over zero-copy and read-only, which code
    written for the pool (Mitsuba's ``Bitmap(array)``, in-place arithmetic) refuses.
    """
    if setup is not None:
        setup[0](*setup[1])
    return pickle.dumps(fn(pickle.loads(item)), protocol=5)


class RayExecutor:
    """Runs shards as Ray tasks on the cluster at ``address``, or on a private local Ray.

    Parameters: ``address`` is the head's ``host:port`` (``None``: start a local Ray of
    ``num_cpus`` CPUs, owned and shut down by this executor); ``max_retries`` bounds the
    re-runs of one shard after a node or worker failure or a transient error;
    ``auth_mode`` is ``RAY_AUTH_MODE`` as configured (only to warn when it is not
    ``token``); ``setup`` runs in the Ray worker before each shard (:func:`run_shard`);
    ``shared_store``: every node mounts the job's store at the same path, so the shard
    tasks store their own results and return digests (``MATFORGE_SHARED_STORE``,
    :mod:`jobapi.executor`). Ray
    is joined by :meth:`start` (else on the first map) and reused
    afterwards; a Ray already initialised in this process (a test's fixture) is used as it
    is, and left running by :meth:`close`.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        *,
        num_cpus: int = 2,
        max_retries: int = 3,
        auth_mode: str | None = None,
        setup: Setup | None = None,
        shared_store: bool = False,
    ) -> None:
        self.address = address
        self.setup = setup
        self.shared_store = shared_store
        self.num_cpus = max(1, num_cpus)
        self.max_retries = max(0, max_retries)
        self.auth_mode = auth_mode
        self._owned = False
        self._pending: dict[Any, int] = {}
        self._task: Any = None

    # -- connection -------------------------------------------------------------------------
    def start(self) -> None:
        """Join the cluster (or start the private local Ray) unless Ray is already up;
        raises :class:`~jobapi.errors.ExecutorUnavailable` when it cannot."""
        if ray.is_initialized():
            return
        if self.address and (self.auth_mode or "").lower() != "token":
            log.warning(
                "connecting to the Ray cluster at %s without RAY_AUTH_MODE=token: anyone who "
                "reaches its ports can run code on it (CVE-2023-48022); see docs/ray.md",
                self.address,
            )
        try:
            if self.address:
                ray.init(
                    address=self.address,
                    namespace="matforge",
                    configure_logging=False,
                    log_to_driver=False,
                )
            else:
                ray.init(
                    address="local",
                    num_cpus=self.num_cpus,
                    include_dashboard=False,
                    object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                    namespace="matforge",
                    configure_logging=False,
                    log_to_driver=False,
                )
        except (ConnectionError, RuntimeError, RayError) as exc:
            where = self.address or "a local Ray"
            raise ExecutorUnavailable(f"cannot start or reach {where}: {exc}") from exc
        self._owned = True

    def _remote(self) -> Any:
        if self._task is None:
            self._task = ray.remote(run_shard).options(
                num_cpus=1,
                max_retries=self.max_retries,
                retry_exceptions=list(TRANSIENT_ERRORS),
            )
        return self._task

    def cluster_cpus(self) -> int:
        """The CPUs of the cluster's live nodes (at least 1)."""
        return max(1, int(ray.cluster_resources().get("CPU", 1)))

    def nodes(self) -> int:
        """The cluster's live nodes."""
        return sum(1 for n in ray.nodes() if n.get("Alive"))

    # -- Executor -----------------------------------------------------------------------------
    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        if not items:
            return
        self.start()
        task = self._remote()
        fn_ref = ray.put(fn)  # once per map, not once per shard
        limit = 2 * self.cluster_cpus()
        pending: dict[Any, int] = {}
        self._pending = pending  # for abort(), from the heartbeat thread
        next_i = 0
        try:
            while next_i < len(items) or pending:
                while next_i < len(items) and len(pending) < limit:
                    item = pickle.dumps(items[next_i], protocol=5)
                    pending[task.remote(fn_ref, item, self.setup)] = next_i
                    next_i += 1
                refs = list(pending)
                ready, _ = ray.wait(refs, num_returns=1)
                if len(refs) > 1:  # every finished shard, not one per scan of the list
                    more, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
                    first = set(ready)
                    ready += [r for r in more if r not in first]
                for ref in ready:
                    i = pending.pop(ref)
                    yield i, self._result(ref, i)
        finally:
            for ref in pending:  # a cancelled or failed job: drop the rest of the batch
                ray.cancel(ref)

    def abort(self) -> None:
        """Cancel (forcibly: the Ray worker is killed) the shards in flight, from any
        thread: the map blocked on them gets their errors at once."""
        for ref in list(self._pending):
            try:
                ray.cancel(ref, force=True)
            except Exception:  # already finished, or the cluster is gone
                log.debug("cancelling a shard failed", exc_info=True)

    def _result(self, ref: Any, i: int) -> Any:
        try:
            return pickle.loads(ray.get(ref))
        except RayTaskError as exc:
            # The shard's own exception, as the local pool would raise it; Ray's wrapper
            # adds the remote traceback, which goes to the log, not to the job's error.
            log.info("shard %d raised remotely:\n%s", i, exc)
            cause = exc.cause
            if isinstance(cause, BaseException):
                raise cause from None
            raise
        except RayError as exc:  # node or worker died more often than max_retries
            raise ShardLost(
                f"shard {i} lost after {self.max_retries} retries on Ray: "
                f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}"
            ) from None

    def describe(self) -> dict[str, Any]:
        nodes = self.nodes() if ray.is_initialized() else 0
        return {"executor": self.name, "executor_nodes": nodes}

    def close(self) -> None:
        """Shut down the private local Ray (or leave a cluster) if this executor joined it."""
        if self._owned and ray.is_initialized():
            ray.shutdown()
        self._owned = False
        self._task = None
