"""What the REST API and the CLI share: submit a spec, run one in process, import a file.

Routes and commands stay thin and call these functions.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from jobapi.context import media_type_for
from jobapi.errors import SpecError
from jobapi.params import JOB_REF, SHA_REF, stored_as_fields, stored_format
from service.settings import Settings
from service.specs import SHORT_JOB_REF, ValidSpec, validate_spec
from service.workers.backend import start_backend
from service.workers.execution import execute_configured, worker_id
from service.workers.executors import executor_for
from storage.artifacts import ArtifactStore
from storage.errors import (
    AmbiguousIdError,
    FormatError,
    IntegrityError,
    NotFoundError,
    TooLargeError,
)
from storage.formats import validate_file
from storage.job_queries import resolve_job_id
from storage.jobs import ArtifactRecord, Job, JobStore


def _strings(obj: Any, path: str) -> Iterator[tuple[str, str]]:
    if isinstance(obj, str):
        yield path, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _strings(v, f"{path}.{k}")
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _strings(v, f"{path}.{i}")


def check_refs(spec: ValidSpec, jobs: JobStore, store: ArtifactStore) -> None:
    """Every ``job:`` / ``sha256:`` ref in the params must exist now (before queueing)."""
    if not _may_hold_refs(spec.canonical):
        return  # the usual case, told from the canonical text without walking the params
    errors: list[tuple[str, str]] = []
    for loc, value in _strings(spec.params.model_dump(mode="json"), "params"):
        m = JOB_REF.match(value)
        if m:
            try:
                job = jobs.get(m["job"])
            except NotFoundError:
                errors.append((loc, f"{value}: no job {m['job']}"))
                continue
            if job.state != "succeeded":
                errors.append((loc, f"{value}: job {job.id} is {job.state}, not succeeded"))
            elif m["name"] not in {a.name for a in job.artifacts}:
                errors.append((loc, f"{value}: job {job.id} has no artifact {m['name']!r}"))
            continue
        m = SHA_REF.match(value)
        if m and not store.exists(m["digest"]):
            errors.append((loc, f"{value}: no such object in the store"))
    if not errors:
        errors = _stored_as_errors(spec, jobs)
    if not errors:
        errors = _external_model_errors(spec.params.model_dump(mode="json"), jobs, store)
    if errors:
        raise SpecError(errors)


def _stored_as_errors(spec: ValidSpec, jobs: JobStore) -> list[tuple[str, str]]:
    """A ref field marked :class:`jobapi.params.StoredAs` (``import.btf``'s ``archive``)
    whose object was not checked as one of its formats when it was stored: refused before
    queueing, from the store's upload records (the job checks again)."""
    errors: list[tuple[str, str]] = []
    for loc, ref, marker in stored_as_fields(spec.params):
        if (m := SHA_REF.match(ref)) is not None:
            digest = m["digest"]
        elif (m := JOB_REF.match(ref)) is not None:
            digest = jobs.artifact(m["job"], m["name"]).digest  # it exists: checked above
        else:
            continue
        records = [(r.name, r.media_type) for r in jobs.upload_records(digest)]
        try:
            stored_format(ref, records, marker)
        except ValueError as exc:
            errors.append((loc, str(exc)))
    return errors


def _may_hold_refs(canonical: str) -> bool:
    """Whether a spec's canonical JSON text may hold a ref or an ``external`` model: every
    string value that is one starts ``"job:`` or ``"sha256:`` there, and every ``external``
    value is the key ``"external":`` (canonical JSON escapes neither, and has no spaces)."""
    return '"job:' in canonical or '"sha256:' in canonical or '"external":' in canonical


def _external_values(obj: Any, loc: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """``(location, value)`` of every ``{"external": {"model", "kind", ...}}`` in ``obj``."""
    if isinstance(obj, dict):
        ext = obj.get("external")
        if isinstance(ext, dict) and isinstance(ext.get("model"), str):
            yield f"{loc}.external", ext
        for k, v in obj.items():
            yield from _external_values(v, f"{loc}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _external_values(v, f"{loc}[{i}]")


def _external_model_errors(
    params: Any, jobs: JobStore, store: ArtifactStore
) -> list[tuple[str, str]]:
    """A user's model file whose signature is not its declared ``kind`` is refused before
    queueing: an ONNX file's inputs (:func:`storage.formats.onnx.check_onnx_file`) or an MLP
    file's ``format`` (``matforge.mlp-brdf/1`` for ``brdf``, ``-btf`` for ``btf``).

    Runs in a worker thread of the web process (the routes call the submission there), so
    it reads no more than it needs: a JSON file's ``format`` from at most its first
    :data:`MODEL_HEAD_BYTES` (:func:`storage.formats.model_files.json_format`; a file
    whose first bytes do not tell is left to the job, which checks it again), an ONNX file
    up to the format's size limit. A check that fails on an object whose bytes no longer
    match its digest reports that instead (the store's own verification). At most
    :data:`MODEL_CHECKS` files are checked at once."""
    errors: list[tuple[str, str]] = []
    for loc, ext in _external_values(params, "params"):
        ref, kind = ext["model"], ext.get("kind")
        if kind not in ("brdf", "btf"):
            continue  # the params model names it
        digest = None
        if (m := SHA_REF.match(ref)) is not None:
            digest = m["digest"]
        elif (m := JOB_REF.match(ref)) is not None:
            try:
                digest = jobs.artifact(m["job"], m["name"]).digest
            except NotFoundError:
                continue  # check_refs names it
        if digest is None or not store.exists(digest):
            continue
        found = _model_file_error(store, digest, ref, kind)
        if found is not None:
            errors.append((f"{loc}.{found[0]}", found[1]))
    return errors


#: Bytes of a stored JSON model file read at submission to find its ``format``.
MODEL_HEAD_BYTES = 256 * 1024
#: Model files checked at once per web process (an ONNX file is parsed whole, up to its
#: format's 64 MiB): more submissions naming models wait, in their worker threads.
MODEL_CHECKS = 2
_MODEL_CHECKS = threading.BoundedSemaphore(MODEL_CHECKS)


def _model_file_error(
    store: ArtifactStore, digest: str, ref: str, kind: str
) -> tuple[str, str] | None:
    """``(field, message)`` of what is wrong with the stored model ``digest`` (named
    ``ref``) as a ``kind`` model, else ``None`` (see :func:`_external_model_errors`); at
    most :data:`MODEL_CHECKS` at once."""
    path = store.path(digest)
    with _MODEL_CHECKS:
        return _check_model_file(store, digest, path, ref, kind)


def _check_model_file(
    store: ArtifactStore, digest: str, path: Path, ref: str, kind: str
) -> tuple[str, str] | None:
    from storage.formats.mlp_model import FORMATS
    from storage.formats.model_files import json_format
    from storage.formats.onnx import check_onnx_file

    try:
        with open(path, "rb") as fh:
            head = fh.read(64).lstrip(b" \t\r\n\xef\xbb\xbf")
        if head.startswith(b"{"):
            fmt = json_format(path, ref, max_bytes=MODEL_HEAD_BYTES)
            found = FORMATS.get(fmt) if fmt is not None else None
            if fmt is not None and found is None:
                return "model", (
                    f"{ref} is a {fmt!r:.80} document, not a model of your own: an MLP file "
                    "(matforge.mlp-brdf/1, matforge.mlp-btf/1) or an ONNX file"
                )
            if found is not None and found != kind:
                return "kind", f"{ref} is a {found} model ({fmt}), not {kind}"
        else:
            check_onnx_file(path, ref, kind)
    except (FormatError, TooLargeError, OSError, ValueError) as exc:
        try:
            store.open_verified(digest)
        except (IntegrityError, NotFoundError) as bad:  # the message names the object
            return "model", str(bad) if ref == f"sha256:{digest}" else f"{ref}: {bad}"
        if isinstance(exc, FormatError | TooLargeError):
            return "model", str(exc)
        return "model", f"{ref}: {exc}"
    return None


def _has_short_ref(obj: Any) -> bool:
    """Whether any string in ``obj`` is a ``job:<prefix>`` ref (iterative, no paths)."""
    stack = [obj]
    while stack:
        value = stack.pop()
        if isinstance(value, dict):
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
        elif isinstance(value, str) and value.startswith("job:") and SHORT_JOB_REF.match(value):
            return True
    return False


def expand_short_refs(raw: Any, jobs: JobStore) -> Any:
    """``raw`` with every ``job:<prefix>/<name>`` (or ``job:<prefix>``) in its params written
    with the full job id, so that a spec's identity (its hash) does not depend on how short
    the user typed the id. Raises ``SpecError`` naming the field for an unknown or
    ambiguous prefix."""
    if not isinstance(raw, dict) or not isinstance(raw.get("params"), dict):
        return raw
    if not _has_short_ref(raw["params"]):
        return raw  # the usual case, found without rebuilding a large spec value by value
    errors: list[tuple[str, str]] = []

    def expand(value: Any, loc: str) -> Any:
        if isinstance(value, dict):
            return {k: expand(v, f"{loc}.{k}") for k, v in value.items()}
        if isinstance(value, list):
            return [expand(v, f"{loc}.{i}") for i, v in enumerate(value)]
        m = SHORT_JOB_REF.match(value) if isinstance(value, str) else None
        if m is None:
            return value
        try:
            return f"job:{resolve_job_id(jobs, m['job'])}{m['rest'] or ''}"
        except (NotFoundError, AmbiguousIdError) as exc:
            errors.append((loc, f"{value}: {exc}"))
            return value

    params = expand(raw["params"], "params")
    if errors:
        raise SpecError(errors)
    return {**raw, "params": params}


def prepare_submission(
    raw: Any, jobs: JobStore, store: ArtifactStore, variant: str | None = None
) -> ValidSpec:
    """What :func:`submit` checks before it queues: ``raw`` validated (short job refs
    written out in full) with every ref existing now. Raises ``SpecError``. ``variant``:
    the Mitsuba variant the workers run (:func:`service.workers.backend.identity_variant`),
    part of the identity of the kinds whose bytes depend on it."""
    spec = validate_spec(expand_short_refs(raw, jobs), variant=variant)
    check_refs(spec, jobs, store)
    return spec


def queue_spec(spec: ValidSpec, jobs: JobStore, store: ArtifactStore) -> tuple[Job, bool]:
    """Queue a prepared spec (or find the identical one whose artifacts are all still in
    ``store``: :func:`lost_results`); returns ``(job, created)``."""
    return jobs.submit(
        kind=spec.kind,
        name=spec.name,
        seed=spec.seed,
        spec_hash=spec.spec_hash,
        spec=spec.document(),
        force=spec.force,
        exclude=() if spec.force else lost_results(spec.spec_hash, jobs, store),
    )


def lost_results(spec_hash: str, jobs: JobStore, store: ArtifactStore) -> list[str]:
    """Succeeded jobs of this spec that must not be reused: an artifact or the manifest is
    gone from the store (moved or deleted by hand) or has the wrong size. Resubmitting the
    spec runs it again, and the same spec writes the same bytes, so the run restores the
    lost objects for every job that refers to them. A cheap ``stat`` per object, newest job
    first, stopping at the first intact one (the one a resubmission returns)."""
    lost: list[str] = []
    while (job := jobs.succeeded_with_hash(spec_hash, exclude=lost)) is not None:
        wanted: list[tuple[str, int | None]] = [(a.digest, a.size) for a in job.artifacts]
        if job.manifest_digest:
            wanted.append((job.manifest_digest, None))
        if all(_present(store, d, size) for d, size in wanted):
            break
        lost.append(job.id)
    return lost


def _present(store: ArtifactStore, digest: str, size: int | None) -> bool:
    try:
        actual = store.size(digest)
    except NotFoundError:
        return False
    return size is None or actual == size


def submit(
    raw: Any, jobs: JobStore, store: ArtifactStore, variant: str | None = None
) -> tuple[Job, bool]:
    """Validate ``raw`` and queue it; returns ``(job, created)``. Raises ``SpecError``.

    Job refs in the params may use a unique prefix of the job id; ``variant`` as in
    :func:`prepare_submission`."""
    return queue_spec(prepare_submission(raw, jobs, store, variant), jobs, store)


def run_in_process(raw: Any, settings: Settings) -> Job:
    """``matforge run``: validate, queue in the local store and run it here, now.

    An identical spec that already succeeded is returned as it is (unless ``force``). A
    job left ``running`` by a process that died (its lease expired) is re-queued first, as
    a server's reaper would, so that it resumes here from its finished shards.
    """
    # BackendUnavailable (MATFORGE_VARIANT cannot run here) before anything is queued.
    settings = settings.with_(variant=start_backend(settings))
    jobs = JobStore(settings.db_path)
    store = ArtifactStore(settings.store_dir)
    jobs.reap(settings.max_attempts)
    job, created = submit(raw, jobs, store, variant=settings.variant)
    if not created and job.state == "succeeded":
        return job
    if job.state == "queued":
        executor = executor_for(settings)
        executor.start()  # ExecutorUnavailable before the claim: the job stays queued
        claimed = jobs.claim(worker_id(), settings.lease_seconds, job_id=job.id)
        try:
            if claimed is not None:
                execute_configured(claimed, settings, jobs=jobs, store=store, executor=executor)
        finally:
            executor.close()
    return jobs.get(job.id)


def import_file(
    path: Path,
    jobs: JobStore,
    store: ArtifactStore,
    *,
    name: str | None = None,
    max_bytes: int | None = None,
    validate: Callable[[Path, str], str] = validate_file,
) -> ArtifactRecord:
    """Validate a user's file by its format and put it in the store.

    ``validate(path, name) -> media type`` checks the format (the web process passes
    :meth:`service.upload_check.UploadChecker.validate`, which decodes in a bounded child).
    Raises ``FormatError`` naming the file when it is malformed or of an unknown type, and
    ``TooLargeError`` above ``max_bytes``.
    """
    label = name or path.name
    size = path.stat().st_size
    if max_bytes is not None and size > max_bytes:
        raise TooLargeError(f"{label}: {size} bytes exceeds the limit of {max_bytes} bytes")
    try:
        media_type = validate(path, label)
    except FormatError as exc:
        # Readers' messages may quote the path they opened: for an upload, a server temp
        # file. Users see the name they gave instead.
        # The whole message: a reader may name a member of the file too (an archive's
        # ``images/slice_002.exr``), in its ``filename``.
        message = str(exc)
        for shown in sorted({str(path.resolve()), str(path), path.name}, key=len, reverse=True):
            message = message.replace(shown, label)
        prefix = f"{label}: "
        problem = message[len(prefix) :] if message.startswith(prefix) else message
        raise FormatError(label, problem) from None
    info = store.put_file(path)
    jobs.record_upload(info.digest, label, media_type or media_type_for(label), info.size)
    return ArtifactRecord(
        name=label,
        digest=info.digest,
        size=info.size,
        media_type=media_type or media_type_for(label),
    )
