"""What params models are built from: the strict base model and the reference types.

References (``../shared/CONTRACT.md``):

- ``job:<job-id>/<artifact-name>``: an artifact of a finished job (:data:`JOB_REF`);
- ``sha256:<64 lowercase hex>``: an object in the store (:data:`SHA_REF`);
- ``job:<job-id>`` with no artifact name: a whole job, e.g. a dataset (:data:`JOB_ID_REF`).

In params models use the annotated types :data:`Ref` (an artifact) and :data:`JobRef` (a
whole job); a kind never writes its own pattern for either.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

JOB_REF = re.compile(
    r"^job:(?P<job>[0-9a-f]{32})/(?P<name>(?!.*\.\.)[A-Za-z0-9_-][A-Za-z0-9._/-]*)\Z"
)
SHA_REF = re.compile(r"^sha256:(?P<digest>[0-9a-f]{64})\Z")
JOB_ID_REF = re.compile(r"^job:(?P<job>[0-9a-f]{32})\Z")


class StrictModel(BaseModel):
    """Base of every params model: unknown fields are errors, values are not coerced
    across types (``"3"`` is not an int), and models are immutable."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


def is_ref(value: str) -> bool:
    """Whether ``value`` is a ``job:<id>/<name>`` or ``sha256:`` artifact reference."""
    return bool(JOB_REF.match(value) or SHA_REF.match(value))


def job_id_of(ref: str) -> str:
    """The 32-hex id of a ``job:<id>`` reference; ``ValueError`` if it is not one."""
    m = JOB_ID_REF.match(ref)
    if m is None:
        raise ValueError(f"not a job reference 'job:<job-id>': {ref!r}")
    return m["job"]


def _check_ref(value: str) -> str:
    if not is_ref(value):
        raise ValueError(
            "must be an artifact reference 'job:<job-id>/<artifact-name>' or "
            "'sha256:<64 lowercase hex>'"
        )
    return value


def _check_job_ref(value: str) -> str:
    if not JOB_ID_REF.match(value):
        raise ValueError("must be a whole job 'job:<job-id>' (in a batch file 'step:<step-name>')")
    return value


#: An artifact reference field: ``job:<id>/<name>`` or ``sha256:<hex>``.
Ref = Annotated[str, AfterValidator(_check_ref)]


@dataclass(frozen=True)
class StoredAs:
    """Marks a :data:`Ref` field (``Annotated[Ref, StoredAs(...)]``) whose object must have
    been validated as one of ``endings`` (upload formats, the keys of
    :data:`storage.formats.VALIDATORS` and ``COMPOUND_VALIDATORS``: ``".btf.zip"``) when it
    was stored. The store's record of the object decides (:func:`stored_format`), never its
    bytes: a PNG with a zip appended passes the PNG check and reads as a zip. Checked at
    submission (422 naming the field) and again by the job
    (:meth:`jobapi.context.JobContext.stored_format`). ``hint`` ends the refusal."""

    endings: tuple[str, ...]
    hint: str = ""


def stored_as_fields(model: BaseModel, loc: str = "params") -> Iterator[tuple[str, str, StoredAs]]:
    """``(location, ref, marker)`` of every set field of ``model`` (and of the models nested
    in it, in lists, tuples and dicts too) marked :class:`StoredAs`."""
    for name, info in type(model).model_fields.items():
        value = getattr(model, name)
        here = f"{loc}.{name}"
        marker = next((m for m in info.metadata if isinstance(m, StoredAs)), None)
        if marker is not None and isinstance(value, str):
            yield here, value, marker
        yield from _nested_stored_as(value, here)


def _nested_stored_as(value: Any, loc: str) -> Iterator[tuple[str, str, StoredAs]]:
    if isinstance(value, BaseModel):
        yield from stored_as_fields(value, loc)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            yield from _nested_stored_as(v, f"{loc}.{i}")
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _nested_stored_as(v, f"{loc}.{k}")


def stored_format(
    ref: str, records: Sequence[tuple[str, str]], marker: StoredAs
) -> tuple[str, str]:
    """``(ending, name)``: the ending of ``marker`` that ``ref``'s object was validated as
    when it was stored, and the name it was uploaded under then, from ``records``, its
    upload records ``(name, media type)``; ``ValueError`` saying what it was stored as
    otherwise (the caller names the field)."""
    from storage.formats import validated_as

    for name, media_type in records:
        ending = validated_as(name, media_type)
        if ending is not None and ending in marker.endings:
            return ending, name
    wanted = " or ".join(f"'{e}'" for e in marker.endings)
    if records:
        seen = ", ".join(f"{name!r} ({media_type})" for name, media_type in records)
        what = f"{ref} was stored as {seen}, not checked as a {wanted} file"
    else:
        what = f"{ref} is not an uploaded {wanted} file (no upload or import stored it)"
    raise ValueError(f"{what}{'; ' + marker.hint if marker.hint else ''}")


#: A whole-job reference field: ``job:<id>`` (a dataset, a set of tables, a run).
JobRef = Annotated[str, AfterValidator(_check_job_ref)]


#: Where a training kind runs torch: ``auto`` (cuda when torch sees a CUDA device, else
#: cpu), ``cpu`` or ``cuda``. Every ``train.*`` kind has a ``device`` field of this type
#: (:func:`device_field`); the runner resolves it at job start
#: (:func:`models.device.pick_device`), fails the job naming the field when ``cuda`` is
#: asked for on a worker without one, and the manifest records the device used.
Device = Literal["auto", "cpu", "cuda"]


def device_field(default: Device = "auto") -> Any:
    """The ``device`` field of a training kind's params (:data:`Device`), with its
    documentation; ``default`` is the kind's."""
    return Field(
        default=default,
        description="Training device: 'auto' takes cuda when torch sees a CUDA device, else "
        "cpu; 'cuda' fails the job on a worker without one. The manifest records the device "
        "used; only cpu is byte-deterministic.",
    )
