"""Worker processes: claim jobs under a lease, run them, recycle; and their supervisor.

``python -m service.workers.worker --data-dir D`` runs one worker. It exits by itself after
``recycle_after_jobs`` jobs, because Mitsuba and Dr.Jit leak memory over long loops; the
:class:`Supervisor` (started by ``matforge serve``) keeps N workers alive, starting a new
one when one exits or dies, or when its beat stalls past the lease (a stopped or frozen
worker, :mod:`~service.workers.liveness`). A worker ends by itself when its supervisor dies.
Heavy work never runs in the web process.

Every worker runs under a memory limit set by the kernel (``MATFORGE_JOB_MEMORY_MB``,
:mod:`~service.workers.memory`): a job past it fails with an error that starts ``out of
memory``, and the worker is replaced before it runs another job.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from jobapi.errors import BackendUnavailable, ExecutorUnavailable
from service.settings import Settings
from service.workers.backend import start_backend
from service.workers.execution import execute_configured, worker_id
from service.workers.executors import executor_for
from service.workers.liveness import Beat, beat_path, end_worker, stalled_for, watch_parent
from service.workers.memory import NATIVE_OOM_SIGNALS, death_message, limit_memory
from storage.artifacts import ArtifactStore
from storage.jobs import JobStore

log = logging.getLogger("matforge.worker")


def run_worker(
    settings: Settings,
    *,
    max_jobs: int | None = None,
    poll_seconds: float = 0.2,
    idle_exit_seconds: float | None = None,
    stop: threading.Event | None = None,
    on_wedged: Callable[[], None] | None = None,
) -> int:
    """Claim and run jobs until ``max_jobs`` ran, ``stop`` is set, the queue stayed empty
    for ``idle_exit_seconds``, or a job ran out of memory (the next job gets a fresh
    process). Returns the number of jobs run. ``on_wedged`` is called when
    a stopped job's runner does not return (:func:`~service.workers.execution.execute`);
    the worker process passes :func:`~service.workers.liveness.end_worker`."""
    # BackendUnavailable (MATFORGE_VARIANT cannot run here): exit before claiming. The
    # shards take the variant resolved here, so they never disagree with the job.
    settings = settings.with_(variant=start_backend(settings))
    jobs = JobStore(settings.db_path)
    store = ArtifactStore(settings.store_dir)
    executor = executor_for(settings)
    executor.start()  # ExecutorUnavailable: exit before claiming, the queue is untouched
    me = worker_id()
    limit = settings.recycle_after_jobs if max_jobs is None else max_jobs
    ran, idle_since = 0, time.monotonic()
    log.info(
        "worker %s started (Mitsuba variant %s, recycle after %d jobs)", me, settings.variant, limit
    )
    try:
        while (limit <= 0 or ran < limit) and not (stop and stop.is_set()):
            jobs.reap(settings.max_attempts)
            job = jobs.claim(me, settings.lease_seconds)
            if job is None:
                if (
                    idle_exit_seconds is not None
                    and time.monotonic() - idle_since > idle_exit_seconds
                ):
                    break
                time.sleep(poll_seconds)
                continue
            log.info("worker %s runs job %s (%s), attempt %d", me, job.id, job.kind, job.attempts)
            state = execute_configured(
                job, settings, jobs=jobs, store=store, executor=executor, on_wedged=on_wedged
            )
            log.info("job %s: %s", job.id, state)
            ran += 1
            idle_since = time.monotonic()
            if state == "failed" and _ran_out_of_memory(jobs, job.id):
                log.warning(
                    "worker %s: job %s ran out of memory; exiting so that a fresh worker "
                    "takes the next job",
                    me,
                    job.id,
                )
                break
    finally:
        executor.close()
        jobs.close()
    return ran


def _ran_out_of_memory(jobs: JobStore, job_id: str) -> bool:
    try:
        error = jobs.get(job_id).error or ""
    except Exception:  # a busy database: keep the worker
        return False
    return error.startswith("out of memory")


class Supervisor:
    """Keeps ``n`` worker processes alive and reaps expired leases.

    Workers are separate OS processes (``python -m service.workers.worker``), so a crash, an
    out-of-memory kill or a SIGKILL of one loses only its job's lease, which the reaper
    turns back into a queued job. A worker whose beat stalled past the lease is killed (with
    its pool processes) and replaced; workers watch this process and end when it dies.

    Each worker gets the memory limit :meth:`~service.settings.Settings.job_memory_limit`
    computes for ``n`` workers (``memory_limit``). A worker that dies of a signal native
    code dies of at that limit (:data:`~service.workers.memory.NATIVE_OOM_SIGNALS`) fails
    the job it was running as out of memory, instead of leaving it to be retried: it would
    only end another worker.
    """

    def __init__(self, settings: Settings, n: int, check_seconds: float = 0.5) -> None:
        self.settings = settings
        self.n = max(0, n)
        self.check_seconds = check_seconds
        self.procs: list[subprocess.Popen[bytes]] = []
        self.started_at: dict[int, float] = {}
        self.started_total = 0
        self.killed_stalled = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        #: Bytes each worker process (and each of its shard processes) may use; ``None``:
        #: no limit.
        self.memory_limit = settings.with_(workers=max(1, self.n)).job_memory_limit()
        self.oom_deaths = 0

    def _spawn(self) -> subprocess.Popen[bytes]:
        cmd = [
            sys.executable,
            "-m",
            "service.workers.worker",
            "--data-dir",
            str(self.settings.data_dir),
            "--parent-pid",
            str(os.getpid()),
        ]
        env = {**os.environ, **self.settings.to_env()}
        env["MATFORGE_JOB_MEMORY_MB"] = str((self.memory_limit or 0) >> 20)
        proc = subprocess.Popen(cmd, env=env, start_new_session=True)
        self.started_at[proc.pid] = time.time()
        self.started_total += 1
        log.info("started worker pid %d", proc.pid)
        return proc

    def worker_pids(self) -> list[int]:
        with self._lock:
            return [p.pid for p in self.procs if p.poll() is None]

    def _kill_stalled(self, p: subprocess.Popen[bytes]) -> bool:
        """Kill worker ``p`` (and its process group) if its beat stalled past the lease."""
        lease = self.settings.lease_seconds
        age = stalled_for(self.settings.data_dir, p.pid, self.started_at.get(p.pid, 0.0), lease)
        if age is None:
            return False
        log.warning(
            "worker pid %d has not beaten for %.1f s (lease %g s): stopped or hung; "
            "killing and replacing it",
            p.pid,
            age,
            lease,
        )
        try:
            os.killpg(p.pid, signal.SIGKILL)  # it leads its session: its pool goes too
        except ProcessLookupError:
            pass
        except PermissionError:
            p.kill()
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            log.error("worker pid %d did not die on SIGKILL", p.pid)
        self.killed_stalled += 1
        return True

    def _forget(self, p: subprocess.Popen[bytes]) -> None:
        self.started_at.pop(p.pid, None)
        beat_path(self.settings.data_dir, p.pid).unlink(missing_ok=True)

    def check(self) -> None:
        """Replace exited or stalled workers and reap expired leases (called periodically)."""
        with self._lock:
            alive = []
            for p in self.procs:
                code = p.poll()
                if code is None and not self._kill_stalled(p):
                    alive.append(p)
                    continue
                self._forget(p)
                if code is None:
                    pass  # killed as stalled, logged there
                elif code == 0:
                    log.info("worker pid %d recycled", p.pid)
                else:
                    log.warning("worker pid %d died (exit %s); replacing it", p.pid, code)
                    if -code in NATIVE_OOM_SIGNALS:
                        self._fail_jobs_of(p.pid, -code)
            while len(alive) < self.n and not self._stop.is_set():
                alive.append(self._spawn())
            self.procs = alive
        try:
            JobStore(self.settings.db_path).reap(self.settings.max_attempts)
        except Exception:
            log.exception("reaper failed")

    def _fail_jobs_of(self, pid: int, signum: int) -> None:
        """Fail the jobs worker ``pid`` was running when it died of ``signum``."""
        worker = f"{worker_id().rpartition(':')[0]}:{pid}"
        try:
            jobs = JobStore(self.settings.db_path)
            try:
                for job_id, who in jobs.running():
                    if who != worker:
                        continue
                    job = jobs.get(job_id)
                    if job.lease_token is None:
                        continue
                    error = death_message(job.kind, job.message, signum, self.memory_limit)
                    if jobs.fail(job_id, job.lease_token, error):
                        self.oom_deaths += 1
                        log.warning("job %s failed: %s", job_id, error)
            finally:
                jobs.close()
        except Exception:
            log.exception("failing the jobs of dead worker pid %d failed", pid)

    def _loop(self) -> None:
        while not self._stop.wait(self.check_seconds):
            self.check()

    def start(self) -> None:
        if self.n:
            log.info(
                "job memory limit: %s per worker process (MATFORGE_JOB_MEMORY_MB)",
                f"{self.memory_limit >> 20} MiB" if self.memory_limit else "none",
            )
        self.check()
        self._thread = threading.Thread(target=self._loop, name="supervisor", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=5)
        with self._lock:
            for p in self.procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            deadline = time.monotonic() + timeout
            for p in self.procs:
                try:
                    p.wait(timeout=max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    p.kill()
                self._forget(p)
            self.procs = []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m service.workers.worker")
    ap.add_argument("--data-dir", type=Path, default=None)
    ap.add_argument("--max-jobs", type=int, default=None)
    ap.add_argument(
        "--parent-pid", type=int, default=None, help="end when this process (the supervisor) dies"
    )
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(name)s %(message)s", stream=sys.stderr
    )
    settings = Settings.from_env()
    if args.data_dir is not None:
        settings = settings.with_(data_dir=args.data_dir)
    stop = threading.Event()
    # SIGTERM: finish nothing new; the running job's lease expires and it is re-queued
    # if we are killed before it ends. We exit after the current job.
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    if args.parent_pid is not None:
        watch_parent(args.parent_pid)
    memory = settings.job_memory_limit()
    if memory is not None:  # before Mitsuba, torch or a pool process starts: all inherit it
        log.info("worker memory limit: %d MiB (MATFORGE_JOB_MEMORY_MB)", limit_memory(memory) >> 20)
    beat = Beat(settings.data_dir, settings.lease_seconds)
    beat.start()
    try:
        run_worker(settings, max_jobs=args.max_jobs, stop=stop, on_wedged=end_worker)
    except ExecutorUnavailable as exc:
        log.error("worker cannot start its executor: %s", exc)
        return 3
    except BackendUnavailable as exc:
        log.error("worker cannot start its renderer: %s", exc)
        return 2
    finally:
        beat.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
