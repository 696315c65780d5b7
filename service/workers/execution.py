"""Running one claimed job: heartbeats, the runner, the manifest, fenced completion.

Used both by the worker processes of ``matforge serve`` and by ``matforge run`` (in
process). The runner's exceptions are mapped here: :class:`JobFailed` becomes the job's
one-line ``error``; :class:`JobCancelled` leaves a cancelled job as it is; a MemoryError
(however it surfaced) is "out of memory in <kind> (<step>)"; anything else is logged with its
traceback and reported as an internal error in one line. The :class:`Heartbeat` watches the
run: no progress for the kind's ``stall_seconds``, or a run past ``timeout_seconds``, fails
the job; any stop kills the shard processes the runner waits on, so the worker is freed.
"""

from __future__ import annotations

import functools
import logging
import math
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from jobapi.context import JobContext, JobLimits
from jobapi.documents import ManifestArtifact, ManifestDocument, ManifestTimings
from jobapi.errors import JobCancelled, JobFailed, SpecError
from jobapi.executor import Executor, InlineExecutor
from jobapi.version import __version__
from service import kinds
from service.settings import Settings
from service.specs import canonical_json, validate_spec
from service.workers.memory import (
    current_limit,
    describe_limit,
    exception_chain,
    is_out_of_memory,
    mentions_allocation_failure,
)
from service.workers.provenance import code_version, package_versions
from storage.artifacts import ArtifactStore
from storage.job_logs import JobLog, log_dir
from storage.jobs import HeartbeatStatus, Job, JobStore
from storage.scratch import scratch_prefix

log = logging.getLogger("matforge.execution")
#: Seconds between two progress lines in a job's log.
LOG_EVERY = 2.0


class _JobLogHandler(logging.Handler):
    """Copies this process's log records into a job's log while it runs the job."""

    def __init__(self, job_log: JobLog) -> None:
        super().__init__(logging.NOTSET)
        self.job_log = job_log
        self.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.job_log.write(self.format(record))
        except Exception:  # never let logging fail the job
            self.handleError(record)


def worker_id() -> str:
    """``"<host>:<pid>"`` of this process."""
    import os

    return f"{socket.gethostname()}:{os.getpid()}"


class Heartbeat:
    """Renews a job's lease every ``lease/3`` seconds in a background thread, publishes the
    latest progress, notices cancellation or a lost lease, and watches that the run moves.

    A live heartbeat alone proves nothing: a runner blocked on shard processes that were
    stopped (SIGSTOP) or hung beats forever. So the thread also fails the job (fenced by its
    lease) when it reports no progress (a new progress value or message; every finished
    shard reports one) for ``stall_seconds``, or runs longer than ``timeout_seconds``
    (:meth:`limit`). On any stop (that, a cancel, a lost lease) it calls ``abort`` (the
    executor kills its shard processes, so a runner blocked on them returns at once) and,
    if the runner still has not returned ``grace`` seconds later, ``on_wedged`` (a worker
    ends its process group; its supervisor starts another): the worker is freed either way.
    """

    def __init__(
        self,
        jobs: JobStore,
        job: Job,
        lease_seconds: float,
        *,
        abort: Callable[[], None] | None = None,
        on_wedged: Callable[[], None] | None = None,
        grace: float | None = None,
    ) -> None:
        assert job.lease_token is not None
        self.jobs, self.job_id, self.token = jobs, job.id, job.lease_token
        self.kind = job.kind
        self.lease = lease_seconds
        self.status: HeartbeatStatus = "ok"
        #: Why the watch failed the job ("stuck: ...", "timed out ..."), if it did.
        self.verdict: str | None = None
        self.stall_seconds: float | None = None
        self.timeout_seconds: float | None = None
        self.abort, self.on_wedged = abort, on_wedged
        #: Called with each new progress line the beat publishes (the job's log), at most
        #: one every :data:`LOG_EVERY` seconds.
        self.on_progress: Callable[[str], None] | None = None
        self._logged: tuple[str | None, float] = (None, -math.inf)
        self.grace = max(5.0, lease_seconds) if grace is None else grace
        self._progress = 0.0
        self._message: str | None = None
        self._dirty = False
        self._last_push = 0.0
        self._started = self._progressed = time.monotonic()
        self._stopped_at: float | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._loop, name=f"heartbeat-{job.id[:8]}", daemon=True
        )

    def limit(self, *, stall_seconds: float | None, timeout_seconds: float | None) -> None:
        """Set the watch's limits (``None``: no limit), counted from the start of the run."""
        self.stall_seconds, self.timeout_seconds = stall_seconds, timeout_seconds

    # Monitor protocol ---------------------------------------------------------------------
    def report(self, progress: float, message: str | None) -> None:
        with self._lock:
            if progress != self._progress or (message is not None and message != self._message):
                self._progressed = time.monotonic()
            self._progress, self._dirty = progress, True
            if message is not None:
                self._message = message
        if time.monotonic() - self._last_push > 0.5:  # keep the dashboard lively
            self.beat()

    @property
    def last_message(self) -> str | None:
        """The last message the runner reported, if any."""
        with self._lock:
            return self._message

    def cancelled(self) -> bool:
        return self.status != "ok" or self.verdict is not None

    def outcome(self) -> str:
        """The run's final state once it stopped: ``failed`` (the watch's verdict),
        ``cancelled`` or ``lost``."""
        if self.verdict is not None:
            return "failed"
        return "cancelled" if self.status == "cancelled" else "lost"

    # ---------------------------------------------------------------------------------------
    def beat(self) -> None:
        with self._lock:
            progress, message, self._dirty = self._progress, self._message, False
        self._last_push = time.monotonic()
        self._log_progress(progress, message, force=False)
        try:
            status = self.jobs.heartbeat(self.job_id, self.token, self.lease, progress, message)
        except Exception:  # a busy database must not kill the job; the next beat retries
            log.exception("heartbeat for %s failed", self.job_id)
            return
        if status != "ok":
            self.status = status

    def _log_progress(self, progress: float, message: str | None, *, force: bool) -> None:
        if self.on_progress is None or message is None:
            return
        last, at = self._logged
        now = time.monotonic()
        if message != last and (force or now - at >= LOG_EVERY):
            self._logged = (message, now)
            self.on_progress(f"progress {100 * progress:.0f} %: {message}")

    def flush_log(self) -> None:
        """Log the last progress line if the rate limit held it back."""
        with self._lock:
            progress, message = self._progress, self._message
        self._log_progress(progress, message, force=True)

    def _verdict(self, now: float) -> str | None:
        ran, idle = now - self._started, now - self._progressed
        step = f" (last step: {self._message})" if self._message else ""
        if self.timeout_seconds is not None and ran > self.timeout_seconds:
            return (
                f"timed out: still running after {ran:.0f} s, over its time limit of "
                f"{self.timeout_seconds:g} s{step}; raise the spec's timeout_seconds or "
                "make the job smaller"
            )
        if self.stall_seconds is not None and idle > self.stall_seconds:
            return (
                f"stuck: no progress for {idle:.0f} s (the limit for {self.kind} is "
                f"{self.stall_seconds:g} s){step}; a shard process may have been stopped "
                "or hung. Its processes were killed; submit the spec again"
            )
        return None

    def watch(self) -> None:
        """One look at the run (the heartbeat thread calls it after every beat)."""
        now = time.monotonic()
        if not self.cancelled():
            verdict = self._verdict(now)
            if verdict is not None:
                if self.jobs.fail(self.job_id, self.token, verdict):
                    log.warning("job %s (%s) failed: %s", self.job_id, self.kind, verdict)
                    self.verdict = verdict
                else:  # cancelled, or the lease lost, meanwhile
                    self.beat()
        if not self.cancelled():
            return
        if self._stopped_at is None:
            self._stopped_at = now
            if self.abort is not None:
                try:
                    self.abort()
                except Exception:
                    log.exception("stopping the shards of job %s failed", self.job_id)
        elif self.on_wedged is not None and now - self._stopped_at > self.grace:
            log.error(
                "job %s (%s) is %s but its runner has not returned %.0f s later; "
                "ending this worker so that another takes its place",
                self.job_id, self.kind, self.outcome(), now - self._stopped_at,
            )  # fmt: skip
            on_wedged, self.on_wedged = self.on_wedged, None
            on_wedged()

    def _loop(self) -> None:
        interval = max(0.05, self.lease / 3)
        while not self._stop.wait(interval):
            if not self.cancelled():
                self.beat()
            try:
                self.watch()
            except Exception:  # a busy database: look again at the next beat
                log.exception("watching job %s failed", self.job_id)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def crash_message(kind: str, exc: BaseException, step: str | None) -> str:
    """The one-line ``error`` of a job whose runner raised ``exc`` (not a ``JobFailed``).

    Running out of memory is named as such, wherever it happened (in the runner, or in a
    shard process whose MemoryError came back through the pool), however the runtime said
    it (:func:`~service.workers.memory.is_out_of_memory`: numpy, torch, onnxruntime) and
    whatever it led to on the way out (a file closed under a reader's feet used to be
    reported instead: "I/O operation on closed file"); a shard process that died (killed at
    the memory limit, as native code is, or crashed) too. ``step`` is the runner's last
    progress line."""
    at = f" ({step})" if step else ""
    chain = exception_chain(exc)
    if is_out_of_memory(exc):
        return (
            f"out of memory in {kind}{at}: the job needs more memory than this worker could "
            f"allocate under {describe_limit(current_limit())}; use smaller inputs or shards, "
            "or a worker with more memory"
        )
    if any(isinstance(e, BrokenProcessPool) for e in chain):
        return (
            f"out of memory in {kind}{at}, or a crash: a shard process died (killed at "
            f"{describe_limit(current_limit())}, or crashed); see the worker log, then "
            "submit the spec again with smaller inputs"
        )
    return f"internal error in {kind}: {type(exc).__name__}: {_one_line(exc)}"


def failure_message(kind: str, exc: BaseException, step: str | None) -> str:
    """The one-line ``error`` of a job whose runner raised a ``JobFailed`` (or a
    ``SpecError``): its message, unless it wraps a failed allocation (a Mitsuba plugin's
    exception reported as text, e.g. onnxruntime's ``std::bad_alloc`` while a session
    starts), which is named as running out of memory, with the message's first part."""
    text = _one_line(exc)
    if text.startswith("out of memory") or not mentions_allocation_failure(text):
        return text
    at = f" ({step})" if step else ""
    head = text.split(" Traceback (most recent call last)")[0].rstrip(": ")
    head = head if len(head) <= 200 else head[:197] + "..."
    return (
        f"out of memory in {kind}{at}: the job needs more memory than this worker could "
        f"allocate under {describe_limit(current_limit())}; use smaller inputs or shards, "
        f"or a worker with more memory ({head})"
    )


def execute_configured(
    job: Job,
    settings: Settings,
    *,
    jobs: JobStore,
    store: ArtifactStore,
    executor: Executor,
    on_wedged: Callable[[], None] | None = None,
) -> str:
    """:func:`execute` with what ``settings`` configure: the lease, the scratch folder and
    the log folder under the data directory, the archive limits, the stall bound and the
    Mitsuba variant."""
    return execute(
        job,
        jobs=jobs,
        store=store,
        lease_seconds=settings.lease_seconds,
        executor=executor,
        scratch=settings.data_dir / "scratch",
        limits=JobLimits(archive_pixels=settings.archive_max_pixels),
        stall_seconds=settings.stall_seconds,
        log_dir=log_dir(settings.data_dir),
        on_wedged=on_wedged,
        variant=settings.variant,
    )


def execute(
    job: Job,
    *,
    jobs: JobStore,
    store: ArtifactStore,
    lease_seconds: float,
    executor: Executor | None = None,
    scratch: Path | None = None,
    limits: JobLimits | None = None,
    stall_seconds: float | None = None,
    on_wedged: Callable[[], None] | None = None,
    log_dir: Path | None = None,
    variant: str | None = None,
) -> str:
    """Run a job this process has claimed; returns its final state as this worker saw it
    (``"succeeded"``, ``"failed"``, ``"cancelled"`` or ``"lost"``).

    ``limits`` are the operator's limits the runner honours (:class:`~jobapi.context.
    JobLimits`). The run is watched (:class:`Heartbeat`): the spec's ``timeout_seconds``
    (else the kind's) and ``stall_seconds`` (else the kind's) bound it; on a stop the
    executor's ``abort()`` kills its shard processes, and ``on_wedged`` is called if the
    runner still does not return. With ``log_dir`` the run is written to the job's log
    (:class:`storage.job_logs.JobLog`): its start and end, its progress lines and this
    process's log records while it runs. ``variant`` is the Mitsuba variant this process
    resolved (:func:`service.workers.backend.start_backend`), recorded in the manifest."""
    run = functools.partial(
        _execute, job, jobs=jobs, store=store, lease_seconds=lease_seconds, executor=executor,
        scratch=scratch, limits=limits, stall_seconds=stall_seconds, on_wedged=on_wedged,
        variant=variant,
    )  # fmt: skip
    if log_dir is None:
        return run(job_log=None)
    job_log = JobLog(log_dir, job.id)
    job_log.write(f"attempt {job.attempts}: {job.kind} on worker {job.worker or worker_id()}")
    handler = _JobLogHandler(job_log)
    root = logging.getLogger()
    root.addHandler(handler)
    try:
        state = run(job_log=job_log)
    except BaseException as exc:
        job_log.write(f"attempt {job.attempts} ended by {type(exc).__name__}: {exc}")
        raise
    finally:
        root.removeHandler(handler)
    error = jobs.get(job.id).error if state == "failed" else None
    job_log.write(f"attempt {job.attempts}: {state}" + (f": {error}" if error else ""))
    return state


def _execute(
    job: Job,
    *,
    jobs: JobStore,
    store: ArtifactStore,
    lease_seconds: float,
    executor: Executor | None,
    scratch: Path | None,
    limits: JobLimits | None,
    stall_seconds: float | None,
    on_wedged: Callable[[], None] | None,
    job_log: JobLog | None,
    variant: str | None,
) -> str:
    assert job.lease_token is not None
    started = time.time()
    hb = Heartbeat(
        jobs, job, lease_seconds, abort=getattr(executor, "abort", None), on_wedged=on_wedged
    )
    if job_log is not None:
        hb.on_progress = job_log.write
    if scratch is not None:
        scratch.mkdir(parents=True, exist_ok=True)
    workdir = Path(tempfile.mkdtemp(prefix=scratch_prefix(job.id), dir=scratch))
    try:
        with hb:
            try:
                spec = validate_spec(job.spec)
                kind = kinds.get_kind(spec.kind)
                hb.limit(
                    stall_seconds=stall_seconds or kind.stall_seconds,
                    timeout_seconds=spec.timeout_seconds or kind.timeout_seconds,
                )
                ctx = JobContext(
                    job_id=job.id,
                    seed=spec.seed,
                    spec=job.spec,
                    store=store,
                    jobs=jobs,
                    workdir=workdir,
                    monitor=hb,
                    executor=executor,
                    limits=limits,
                    variant=variant,
                )
                kind.runner(spec.params, ctx)
                ctx.check_cancelled()
            except JobCancelled:
                log.info("job %s stopped: %s", job.id, hb.verdict or hb.status)
                return hb.outcome()
            except (JobFailed, SpecError) as exc:
                if hb.cancelled():  # stopped first; what the runner made of it is moot
                    return hb.outcome()
                jobs.fail(job.id, job.lease_token, failure_message(job.kind, exc, hb.last_message))
                return "failed"
            except Exception as exc:
                if hb.cancelled():  # e.g. the pool its shards ran in was killed on a stop
                    log.info("job %s stopped (%s): %r", job.id, hb.verdict or hb.status, exc)
                    return hb.outcome()
                log.exception("job %s (%s) crashed", job.id, job.kind)
                jobs.fail(job.id, job.lease_token, crash_message(job.kind, exc, hb.last_message))
                return "failed"
        finished = time.time()
        arts = sorted(ctx.artifacts.values(), key=lambda a: a.name)
        where = (executor if executor is not None else InlineExecutor()).describe()
        manifest = ManifestDocument(
            job=job.id,
            kind=job.kind,
            name=job.name,
            spec=job.spec,
            spec_hash=job.spec_hash,
            seed=spec.seed,
            artifacts=[
                ManifestArtifact(name=a.name, digest=a.digest, size=a.size, media_type=a.media_type)
                for a in arts
            ],
            matforge_version=__version__,
            code_version=code_version(),
            packages=package_versions(),
            worker=job.worker,
            # Where the shards ran: "process" (the local pool) or "ray", and how many
            # machines (Ray: the live nodes when the job finished).
            executor=str(where["executor"]),
            executor_nodes=int(where["executor_nodes"]),
            # The Mitsuba variant the job's processes used (MATFORGE_VARIANT, resolved), and
            # the torch device a training kind ran on (null for the other kinds).
            variant=variant,
            device=ctx.device,
            attempt=job.attempts,
            timings=ManifestTimings(
                started=started,
                finished=finished,
                run_seconds=finished - started,
                # what the kind timed itself (JobContext.measure), e.g. render_seconds
                measured=dict(sorted(ctx.measured.items())),
            ),
        )
        minfo = store.put_bytes((canonical_json(manifest) + "\n").encode())
        # The runner's last progress line (e.g. a throughput) stays visible after success.
        last = hb.last_message
        done = f"done: {last}" if last and last.strip().lower() != "done" else "done"
        if jobs.complete(job.id, job.lease_token, arts, minfo.digest, message=done[:1000]):
            return "succeeded"
        state = jobs.get(job.id).state
        return state if state in ("cancelled", "failed") else "lost"
    finally:
        hb.flush_log()
        shutil.rmtree(workdir, ignore_errors=True)
