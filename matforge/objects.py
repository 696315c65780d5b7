"""The typed objects :class:`matforge.Client` returns: each is the pydantic model the server
answers with (``service/schemas.py``), its fields typed attributes, and ``.raw`` the whole
document as the server sent it (a field a newer server adds is in ``.raw`` and, as an
attribute, in ``model_extra``).

- :class:`Job`: a job document (``GET /api/jobs/{id}``), its ``artifacts`` :class:`Artifact`;
- :class:`Artifact`: one artifact of a job (name, digest, size, media type);
- :class:`ResultRow`: one measured value (``GET /api/results``);
- :class:`Kind`: a registered job kind (``GET /api/kinds``);
- :class:`Upload`: a stored upload (``POST /api/artifacts``).

For one release they also read like the dicts the client returned before: ``job["state"]``
and ``{**row}`` (with a :class:`DeprecationWarning`; write ``job.state``, ``row.raw``) and
``job == {...}`` (equal when ``.raw`` is).
"""

from __future__ import annotations

import warnings
from collections.abc import KeysView, Mapping
from typing import Any, Self

from pydantic import BaseModel, ConfigDict, PrivateAttr

from service.schemas import (
    ArtifactPublic,
    JobPublic,
    KindPublic,
    ResultRowPublic,
    UploadPublic,
)

__all__ = ["Artifact", "Job", "Kind", "ResultRow", "Upload"]


class _Typed(BaseModel):
    """A server document as its typed model, with ``.raw`` the document itself."""

    model_config = ConfigDict(extra="allow", frozen=True)
    _raw: dict[str, Any] = PrivateAttr(default_factory=dict)

    @classmethod
    def of(cls, raw: Mapping[str, Any]) -> Self:
        """The typed object of the document ``raw`` (validated against the model)."""
        obj = cls.model_validate(raw)
        obj._raw = dict(raw)
        return obj

    @property
    def raw(self) -> dict[str, Any]:
        """The whole document, as the server sent it."""
        return self._raw

    def _deprecated_key(self, key: str) -> None:
        name = type(self).__name__
        warnings.warn(
            f"reading a {name} as a dict ({key}) is deprecated and goes in the next release: "
            f"use its attributes ({name.lower()}.<field>) or {name.lower()}.raw",
            DeprecationWarning,
            stacklevel=3,
        )

    def __getitem__(self, key: str) -> Any:
        self._deprecated_key(f"[{key!r}]")
        return self._raw[key]

    def get(self, key: str, default: Any = None) -> Any:
        """Deprecated: the dict-style read of the document (``.raw.get``)."""
        self._deprecated_key(f".get({key!r})")
        return self._raw.get(key, default)

    def keys(self) -> KeysView[str]:
        """Deprecated: the document's keys (``.raw.keys()``), so that ``{**row}`` works."""
        self._deprecated_key(".keys()")
        return self._raw.keys()

    def __eq__(self, other: object) -> bool:
        if isinstance(other, _Typed):
            return type(self) is type(other) and self._raw == other._raw
        if isinstance(other, Mapping):  # the dict documents of the previous release
            return self._raw == dict(other)
        return NotImplemented

    __hash__ = None  # type: ignore[assignment]


class Artifact(_Typed, ArtifactPublic):
    """One artifact of a job: ``name``, ``digest`` (64 hex), ``size`` (bytes),
    ``media_type``; :meth:`matforge.Client.read` or :meth:`~matforge.Client.fetch` with
    :attr:`ref` gets its bytes."""

    @property
    def ref(self) -> str:
        """``sha256:<digest>``, usable in job specs and by :meth:`matforge.Client.fetch`."""
        return f"sha256:{self.digest}"


class Job(_Typed, JobPublic):
    """A job document: ``id``, ``kind``, ``state`` (queued, running, succeeded, failed,
    cancelled), ``progress`` (0..1), ``error``, ``spec``, ``artifacts``, ..."""

    artifacts: list[Artifact]  # type: ignore[assignment]

    @classmethod
    def of(cls, raw: Mapping[str, Any]) -> Self:
        job = super().of(raw)
        for art, doc in zip(job.artifacts, raw.get("artifacts") or [], strict=True):
            art._raw = dict(doc)
        return job

    @property
    def ref(self) -> str:
        """``job:<id>``, usable in job specs."""
        return f"job:{self.id}"

    @property
    def done(self) -> bool:
        """Whether the job is finished (succeeded, failed or cancelled)."""
        return self.state in ("succeeded", "failed", "cancelled")


class ResultRow(_Typed, ResultRowPublic):
    """One measured value: ``job``, ``kind``, ``metric``, ``value``, ``lower_is_better``,
    what it was measured on (``dataset``, ``scene``, ``candidate``, ``material``) and its
    costs (``ns_per_eval``, ``ms_per_frame``, ``bytes_per_material``, ...)."""


class Kind(_Typed, KindPublic):
    """A registered job kind: ``name``, ``summary``, ``artifacts`` (fixed names),
    ``params_schema`` (JSON schema), ``plugin`` (the package that adds it, or ``None``)."""


class Upload(_Typed, UploadPublic):
    """A stored upload: ``digest``, ``ref`` (``sha256:<digest>``, usable in specs),
    ``size``, ``media_type``, ``name``."""
