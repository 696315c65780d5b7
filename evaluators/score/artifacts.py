"""Artifact kinds: what ``score`` can load and score, and how it tells them apart.

An artifact kind (:class:`ArtifactKind`) is registered with :func:`register_artifact_kind`
by the module that implements it; :mod:`evaluators.score.kind` imports the explicit list of
those modules (:mod:`evaluators.score.images`, :mod:`evaluators.score.brdf`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evaluators.score.params import ScoreParams
from jobapi.errors import FormatError, JobFailed

if TYPE_CHECKING:
    from jobapi.context import JobContext


@dataclass(frozen=True)
class Loaded:
    """An input artifact: its ref, artifact kind and decoded data."""

    ref: str
    kind: str
    data: Any


@dataclass(frozen=True)
class ScoreResult:
    """What a scorer returns: ``{label: {metric: value}}`` and the settings it used."""

    metrics: dict[str, dict[str, float | None]]
    settings: dict[str, Any]


Scorer = Callable[[Loaded, dict[str, Loaded], ScoreParams, "JobContext"], ScoreResult]


@dataclass(frozen=True)
class ArtifactKind:
    """A kind of artifact ``score`` understands.

    ``media_types``, ``extensions`` and ``magic`` (leading bytes) identify it, in that
    order, then ``detect(path)`` where given; ``load(path, name)`` decodes it (raising
    ``FormatError``); ``scorer`` scores candidates of the same kind and of the kinds named in
    ``candidate_kinds``; ``metrics`` lists the metric names it supports. ``bind(data,
    material)`` marks a *model* kind: it returns the loaded data of one material (raising
    ``FormatError`` for an unknown one); model kinds are candidates only. ``space``: the
    space its metrics are measured in (:data:`jobapi.metric_names.SPACES`, ``"image"``,
    ``"brdf"``), which names its result rows' metrics (``image.mae``, ``brdf.mae``);
    ``None`` for metrics of one space only.
    """

    name: str
    description: str
    media_types: tuple[str, ...]
    extensions: tuple[str, ...]
    magic: bytes
    load: Callable[[Path, str], Any]
    scorer: Scorer
    metrics: tuple[str, ...]
    candidate_kinds: tuple[str, ...] = ()
    detect: Callable[[Path], bool] | None = None
    bind: Callable[[Any, str], Any] | None = None
    space: str | None = None


ARTIFACT_KINDS: dict[str, ArtifactKind] = {}


def register_artifact_kind(kind: ArtifactKind) -> ArtifactKind:
    """Teach ``score`` a new kind of artifact (re-registering a name replaces it)."""
    ARTIFACT_KINDS[kind.name] = kind
    return kind


def identify(name: str, media_type: str, path: Path) -> ArtifactKind | None:
    """The artifact kind of a stored object, from its media type, name or first bytes."""
    for kind in ARTIFACT_KINDS.values():
        if media_type in kind.media_types:
            return kind
    suffix = Path(name).suffix.lower()
    for kind in ARTIFACT_KINDS.values():
        if suffix and suffix in kind.extensions:
            return kind
    with open(path, "rb") as fh:
        head = fh.read(16)
    for kind in ARTIFACT_KINDS.values():
        if kind.magic and head.startswith(kind.magic):
            return kind
    for kind in ARTIFACT_KINDS.values():
        if kind.detect is not None and kind.detect(path):
            return kind
    return None


def load_input(ref: str, role: str, ctx: JobContext, material: str | None = None) -> Loaded:
    """Load ``ref``; ``material`` picks one material of a model kind (and requires one)."""
    record = ctx.ref_record(ref)
    path = ctx.resolve(ref)
    kind = identify(record.name, record.media_type, path)
    if kind is None:
        known = ", ".join(f"{k.description}" for k in ARTIFACT_KINDS.values())
        raise JobFailed(
            f"{role} {ref}: cannot score {record.name} ({record.media_type}); known kinds: {known}"
        )
    if kind.bind is None and material is not None:
        raise JobFailed(
            f"{role}: {{model, material}} needs a trained model, but {ref} is {kind.description}"
        )
    if kind.bind is not None and material is None:
        if role == "reference":
            raise JobFailed(
                f"reference {ref} is {kind.description}; a model can only be a candidate"
            )
        raise JobFailed(
            f"{role}: {ref} is {kind.description}; name one of its materials with "
            f'{{"model": "{ref}", "material": NAME}}'
        )
    try:
        data = kind.load(path, ref)
        if kind.bind is not None and material is not None:
            data = kind.bind(data, material)
    except FormatError as exc:
        raise JobFailed(f"{role}: {exc}") from None
    shown = ref if material is None else f"{ref}#{material}"
    return Loaded(ref=shown, kind=kind.name, data=data)
