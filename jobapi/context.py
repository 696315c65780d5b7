"""The context a job runner receives: seed, progress, cancellation, shards, artifacts.

A runner is ``runner(params, ctx)``. It reads inputs with :meth:`JobContext.resolve`, reports
progress with :meth:`JobContext.progress`, splits heavy work with
:meth:`JobContext.map_shards`, and writes every result with ``ctx.put_*``. It never touches
the job store, the server or the environment.
"""

from __future__ import annotations

import hashlib
import json
import math
import pickle
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from jobapi.documents import check_document, check_typed
from jobapi.errors import IntegrityError, JobCancelled, JobFailed, NotFoundError
from jobapi.executor import Executor, InlineExecutor, StoreShard, uses_shared_store
from jobapi.params import JOB_REF, SHA_REF, StoredAs, stored_format
from storage.artifacts import ArtifactStore, ObjectInfo
from storage.formats.btf_folder import MAX_ARCHIVE_PIXELS
from storage.formats.media import media_type_for
from storage.jobs import ArtifactRecord, Job, JobStore

#: Shard key prefix of a published live document (``:`` never occurs in an artifact name,
#: so these keys cannot meet the shard keys of :meth:`JobContext.map_artifact_shards`).
LIVE_PREFIX = "live:"


@dataclass(frozen=True)
class JobLimits:
    """The operator's limits a runner honours, from the service's settings (a spec cannot
    raise them). ``archive_pixels``: the most pixels all the images of an uploaded archive
    may decode to (``MATFORGE_ARCHIVE_MPIX``)."""

    archive_pixels: int = MAX_ARCHIVE_PIXELS


class Monitor(Protocol):
    """Where progress goes and where cancellation comes from (the worker's heartbeat)."""

    def report(self, progress: float, message: str | None) -> None: ...

    def cancelled(self) -> bool: ...


class NullMonitor:
    """A monitor that records the last progress and is never cancelled."""

    def __init__(self) -> None:
        self.progress = 0.0
        self.message: str | None = None

    def report(self, progress: float, message: str | None) -> None:
        self.progress, self.message = progress, message

    def cancelled(self) -> bool:
        return False


def _check_name(name: str) -> None:
    if not name or name.startswith("/") or ".." in name.split("/"):
        raise ValueError(f"bad artifact name {name!r}")


class JobContext:
    """Everything a runner may use. Attributes:

    - ``job_id``: 32-hex job id; ``seed``: the spec's seed; ``workdir``: a private scratch
      directory, removed after the job.
    - ``store``: the artifact store (use :meth:`resolve` / :meth:`put_bytes` instead).
    - ``limits``: the operator's :class:`JobLimits`.
    - ``variant``: the Mitsuba variant this process resolved at start-up
      (``MATFORGE_VARIANT``; ``None`` when the caller resolved none); Mitsuba itself is
      loaded with it by :func:`materials.backend.load_mitsuba`.
    - ``device``: the torch device a training kind ran on, once it said so
      (:meth:`use_device`); both go into the job's manifest.
    """

    def __init__(
        self,
        *,
        job_id: str,
        seed: int,
        spec: dict[str, Any],
        store: ArtifactStore,
        jobs: JobStore,
        workdir: Path,
        monitor: Monitor | None = None,
        executor: Executor | None = None,
        limits: JobLimits | None = None,
        variant: str | None = None,
    ) -> None:
        self.job_id = job_id
        self.seed = seed
        self.spec = spec
        self.store = store
        self.jobs = jobs
        self.workdir = workdir
        self.monitor: Monitor = monitor or NullMonitor()
        self.executor: Executor = executor or InlineExecutor()
        self.limits = limits or JobLimits()
        self.variant = variant
        self.device: str | None = None
        self.artifacts: dict[str, ArtifactRecord] = {}
        #: Timings the kind measured itself (:meth:`measure`), kept in the job's manifest.
        self.measured: dict[str, Any] = {}
        self._published: dict[str, float] = {}

    def use_device(self, device: str) -> None:
        """Record the torch device (``"cpu"`` or ``"cuda"``) the job trains on, as resolved
        from its ``device`` param; the manifest shows it."""
        self.device = device

    # -- randomness ----------------------------------------------------------------------
    def rng(self, stream: int | str = 0) -> np.random.Generator:
        """A numpy Generator seeded from ``(seed, stream)``: independent per stream, the same
        on every run of the same spec."""
        tag = (
            stream
            if isinstance(stream, int)
            else int.from_bytes(hashlib.sha256(str(stream).encode()).digest()[:8], "little")
        )
        return np.random.default_rng(np.random.SeedSequence([self.seed, tag]))

    def sub_seed(self, stream: int | str) -> int:
        """A 32-bit seed derived from ``(seed, stream)``, for libraries that take an int."""
        return int(self.rng(stream).integers(0, 2**31 - 1))

    # -- progress and cancellation -------------------------------------------------------
    def progress(self, fraction: float, message: str | None = None) -> None:
        """Report progress in [0, 1] with an optional one-line message; raises
        :class:`JobCancelled` if the job was cancelled meanwhile."""
        self.monitor.report(min(1.0, max(0.0, float(fraction))), message)
        self.check_cancelled()

    def cancelled(self) -> bool:
        return self.monitor.cancelled()

    def check_cancelled(self) -> None:
        if self.monitor.cancelled():
            raise JobCancelled(f"job {self.job_id} was cancelled")

    # -- inputs --------------------------------------------------------------------------
    def input_job(self, job_id: str, field: str, kind: str | None = None) -> Job:
        """The succeeded job a param names (``job:<id>`` without the prefix), else
        :class:`JobFailed` naming ``field``: no such job, another ``kind``, not succeeded."""
        try:
            job = self.jobs.get(job_id)
        except NotFoundError:
            raise JobFailed(f"{field}: no job {job_id}") from None
        if kind is not None and job.kind != kind:
            raise JobFailed(f"{field}: job {job_id} is a {job.kind} job, not {kind}")
        if job.state != "succeeded":
            raise JobFailed(f"{field}: job {job_id} is {job.state}, not succeeded")
        return job

    def ref_record(self, ref: str) -> ArtifactRecord:
        """The record (name, digest, size, media type) behind a ``job:`` or ``sha256:`` ref."""
        m = JOB_REF.match(ref)
        if m:
            try:
                return self.jobs.artifact(m["job"], m["name"])
            except NotFoundError as exc:
                raise JobFailed(f"input {ref}: {exc}") from None
        m = SHA_REF.match(ref)
        if m:
            digest = m["digest"]
            if not self.store.exists(digest):
                raise JobFailed(f"input {ref}: no such object in the store")
            rec = self.jobs.find_digest(digest)
            return rec or ArtifactRecord(
                name=digest,
                digest=digest,
                size=self.store.size(digest),
                media_type="application/octet-stream",
            )
        raise JobFailed(f"not an artifact reference: {ref!r}")

    def stored_format(self, ref: str, field: str, marker: StoredAs) -> tuple[str, str]:
        """``(ending, name)``: the ending of ``marker`` (:class:`jobapi.params.StoredAs`)
        that ``ref``'s object was validated as when it was stored, and the name it was
        uploaded under then, from the store's upload records of it (never from its bytes);
        :class:`JobFailed` naming ``field`` otherwise."""
        digest = self.ref_record(ref).digest
        records = [(r.name, r.media_type) for r in self.jobs.upload_records(digest)]
        try:
            return stored_format(ref, records, marker)
        except ValueError as exc:
            raise JobFailed(f"{field}: {exc}") from None

    def resolve(self, ref: str) -> Path:
        """A verified, read-only path to the bytes of ``ref``."""
        rec = self.ref_record(ref)
        try:
            return self.store.open_verified(rec.digest)
        except Exception as exc:  # missing or corrupt object
            raise JobFailed(f"input {ref}: {exc}") from None

    def read_ref(self, ref: str) -> bytes:
        return self.resolve(ref).read_bytes()

    # -- outputs -------------------------------------------------------------------------
    def put_bytes(self, name: str, data: bytes, media_type: str | None = None) -> ArtifactRecord:
        """Store ``data`` as the artifact ``name`` of this job."""
        _check_name(name)
        info = self.store.put_bytes(data)
        return self._record(name, info.digest, info.size, media_type)

    def put_json(self, name: str, obj: Any) -> ArtifactRecord:
        """Store ``obj`` as pretty, key-sorted JSON (deterministic bytes). A document the
        job's kind declares (``Kind.documents``) must be of its type, and a chart document
        (``curves.json``, ``pareto.json``) of its type even if undeclared (:mod:`jobapi.documents`):
        :class:`~jobapi.documents.DocumentError` otherwise, which fails the job."""
        typed = self._documents().get(name)
        if typed is not None:
            check_typed(name, obj, typed)  # a chart document's type brings its rules
        else:
            check_document(name, obj)
        text = json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n"
        return self.put_bytes(name, text.encode(), "application/json")

    def _documents(self) -> Mapping[str, type]:
        # The typed documents of the job's kind (none for a spec without a registered kind).
        from jobapi.kinds import registered

        kind = registered().get(str(self.spec.get("kind")))
        return kind.documents if kind is not None else {}

    def measure(self, name: str, value: float | dict[str, Any]) -> None:
        """Record what the kind measured itself: a time in seconds (``render_seconds``: the
        render's own passes, without loading Mitsuba, the scene and JIT compilation), or a
        JSON document of timings (``cost``: a score's per-candidate ``ns_per_eval``).
        Timings are not artifacts (same spec, same bytes): they go to the job's manifest
        under ``timings.measured``, where result rows read them
        (:attr:`jobapi.rows.JobFacts.measured`). ``name`` is a short identifier; a time is
        a finite number >= 0; a document must be JSON without NaN."""
        if not re.fullmatch(r"[a-z][a-z0-9_]{0,63}", name):
            raise ValueError(f"a measurement's name is a short identifier, got {name!r}")
        if isinstance(value, dict):
            try:
                self.measured[name] = json.loads(json.dumps(value, allow_nan=False))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"measurement {name}: not a JSON document: {exc}") from None
            return
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"measurement {name}: {value!r} is not a finite time >= 0")
        self.measured[name] = float(value)

    def publish(self, name: str, obj: Any, *, min_interval_s: float = 1.0) -> bool:
        """Publish ``obj`` (JSON) as the live state of ``name`` while the job runs, e.g. its
        training curves so far, for the dashboard (``GET /api/jobs/{id}/live/{name}``).

        A later publication replaces an earlier one; publications closer than
        ``min_interval_s`` to the previous one are dropped (returns ``False``), and so is a
        document that is not valid JSON (NaN): live views are best effort. Nothing here is
        an artifact: when the job succeeds its artifacts are what count, and the live
        documents are no longer kept. A chart document of the wrong shape is a bug of the
        kind, not a hiccup: :class:`~jobapi.documents.DocumentError`, as ``put_json`` raises.
        """
        now = time.monotonic()
        if now - self._published.get(name, -math.inf) < min_interval_s:
            return False
        try:
            text = json.dumps(obj, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError):
            return False
        check_document(name, obj)
        info = self.store.put_bytes(text.encode())
        self.jobs.record_shard(self.job_id, LIVE_PREFIX + name, info.digest)
        self._published[name] = now
        return True

    # -- shards --------------------------------------------------------------------------
    def map_shards(
        self,
        fn: Callable[[Any], Any],
        items: Sequence[Any],
        *,
        keys: Sequence[str] | None = None,
        label: str = "shard",
        progress_range: tuple[float, float] = (0.0, 1.0),
    ) -> list[Any]:
        """Run ``fn(item)`` for every item through the executor and return the results in
        item order.

        Each finished shard's result is stored (pickled) in the artifact store and recorded
        against the job under its key (default: its index), so a re-run of the job after a
        crash loads finished shards instead of recomputing them. ``fn`` must be a
        module-level function and its result picklable and deterministic.
        """
        keys = list(keys) if keys is not None else [f"{label}-{i:05d}" for i in range(len(items))]
        if len(keys) != len(items) or len(set(keys)) != len(keys):
            raise ValueError("map_shards: keys must be unique, one per item")
        done = self.jobs.shards(self.job_id)
        results: list[Any] = [None] * len(items)
        todo: list[int] = []
        for i, key in enumerate(keys):
            if key in done and self.store.verify(done[key]):
                results[i] = pickle.loads(self.store.read(done[key]))
            else:
                todo.append(i)
        lo, hi = progress_range
        n_done = len(items) - len(todo)
        self._report_resumed(n_done, len(items), label, progress_range)
        for j, result in self.executor.map(fn, [items[i] for i in todo]):
            i = todo[j]
            info = self.store.put_bytes(pickle.dumps(result, protocol=5))
            self.jobs.record_shard(self.job_id, keys[i], info.digest)
            results[i] = result
            n_done += 1
            self.progress(lo + (hi - lo) * n_done / len(items), f"{label}s: {n_done}/{len(items)}")
        return results

    def map_artifact_shards(
        self,
        fn: Callable[[Any], bytes],
        items: Sequence[Any],
        names: Sequence[str],
        *,
        media_type: str | None = None,
        on_result: Callable[[int, Path], None] | None = None,
        label: str = "shard",
        progress_range: tuple[float, float] = (0.0, 1.0),
    ) -> list[ArtifactRecord]:
        """Run ``fn(item) -> bytes`` for every item and store each result as the artifact
        ``names[i]`` as soon as it arrives: results stream to the store, never all in memory
        (a paper-scale dataset is tens of gigabytes).

        Each finished shard is recorded against the job under its artifact name, so a re-run
        after a crash registers the stored bytes again (verified, not re-read) instead of
        recomputing them. ``on_result(i, path)`` is called once per shard, in completion
        order, with a verified read-only path to its bytes (to summarise it on the way).

        With an executor whose shards see this store at the same path
        (:func:`~jobapi.executor.uses_shared_store`, ``MATFORGE_SHARED_STORE``), each shard
        task writes its own bytes into the store (:class:`~jobapi.executor.StoreShard`) and
        returns their digest and size; this thread checks that the object is there with
        that size (a ``stat``) and records it. The artifacts are the same bytes either way.
        """
        if len(names) != len(items) or len(set(names)) != len(names):
            raise ValueError("map_artifact_shards: names must be unique, one per item")
        for name in names:
            _check_name(name)
        done = self.jobs.shards(self.job_id)
        records: list[ArtifactRecord | None] = [None] * len(items)
        todo: list[int] = []
        for i, name in enumerate(names):
            if name in done and self.store.verify(done[name]):
                digest = done[name]
                records[i] = self._record(name, digest, self.store.size(digest), media_type)
                if on_result is not None:
                    on_result(i, self.store.open_verified(digest))
            else:
                todo.append(i)
        lo, hi = progress_range
        n_done = len(items) - len(todo)
        self._report_resumed(n_done, len(items), label, progress_range)
        shared = uses_shared_store(self.executor)
        task = StoreShard(fn, str(self.store.root.resolve())) if shared else fn
        for j, data in self.executor.map(task, [items[i] for i in todo]):
            i = todo[j]
            if shared:  # the shard task stored it; check it is there, cheaply, and record it
                info: ObjectInfo = data
                try:
                    self.store.check_stored(info)
                except (NotFoundError, IntegrityError) as exc:
                    raise JobFailed(
                        f"{names[i]}: its shard task stored it, but {exc}: with "
                        "MATFORGE_SHARED_STORE=1 every node must mount the store at "
                        f"{self.store.root.resolve()}"
                    ) from None
                rec = self._record(names[i], info.digest, info.size, media_type)
            else:
                rec = self.put_bytes(names[i], data, media_type)
            self.jobs.record_shard(self.job_id, names[i], rec.digest)
            records[i] = rec
            del data
            if on_result is not None:
                on_result(i, self.store.open_verified(rec.digest))
            n_done += 1
            self.progress(lo + (hi - lo) * n_done / len(items), f"{label}s: {n_done}/{len(items)}")
        return [r for r in records if r is not None]

    def _report_resumed(
        self, n_done: int, n: int, label: str, progress_range: tuple[float, float]
    ) -> None:
        if n:
            lo, hi = progress_range
            self.progress(
                lo + (hi - lo) * n_done / n, f"{label}s: {n_done}/{n} (resumed)" if n_done else None
            )

    def _record(self, name: str, digest: str, size: int, media_type: str | None) -> ArtifactRecord:
        rec = ArtifactRecord(
            name=name, digest=digest, size=size, media_type=media_type or media_type_for(name)
        )
        self.artifacts[name] = rec
        return rec
