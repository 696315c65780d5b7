"""``stability.json`` of ``report.stability``: the one definition of the document.

:func:`evaluators.report.stability.run_stability` builds it; ``put_json`` validates it
against :class:`StabilityDocument`; the summary reads it with
:func:`jobapi.documents.read_typed`; the kinds reference lists its fields. A run's model
checks (a kind's ``checks``: albedo, reciprocity, ...) add their own keys to it, and the
configurations and families are rows of the report's own (``configs``, ``families`` of
:mod:`evaluators.report.stability`), typed as objects.
"""

from __future__ import annotations

from typing import Any, NotRequired

from pydantic import ConfigDict, with_config
from typing_extensions import TypedDict

from jobapi.documents import document


@document
class StabilityConvergence(TypedDict):
    """Whether a run's training loss flattened (:func:`evaluators.metrics.convergence.
    convergence`; a score job has only ``flattened`` ``null`` and ``why``)."""

    flattened: bool | None
    """Flattened (``null``: not known: too few points, a last loss not finite, no
    training)."""
    why: str
    """Why, in words."""
    points: NotRequired[int]
    """Finite loss points."""
    tolerance: NotRequired[float]
    """The relative drop below which the loss counts as flat."""
    second_half_drop: NotRequired[float]
    """Relative drop from the tenth around the middle to the last tenth."""
    last_tenth_drop: NotRequired[float]
    """Relative drop over the last tenth."""
    mid_mean: NotRequired[float]
    """Mean loss of the tenth around the middle."""
    last_mean: NotRequired[float]
    """Mean loss of the last tenth."""


@with_config(ConfigDict(extra="allow", use_attribute_docstrings=True))
class StabilityRun(TypedDict):
    """One run checked (a kind's model checks add their own keys)."""

    run: str
    """Its ``job:<id>``."""
    kind: str
    """Its kind."""
    candidate: str | None
    """Its candidate (``null``: a score job, see ``label``)."""
    seed: int
    """Its seed."""
    metric: str | None
    """The headline error metric (the kind's; a score job: the render metric)."""
    error: float | None
    """The run's headline error (``null``: a score job, or none measured)."""
    convergence: StabilityConvergence
    """Whether its loss flattened."""
    label: NotRequired[str]
    """A score job's label."""
    candidates: NotRequired[dict[str, float]]
    """A score job's value per candidate."""


@document
class StabilityDocument(TypedDict):
    """``stability.json`` of ``report.stability``: seed spread, worst seeds, convergence and
    the errors per family and failure case."""

    format: str
    """``matforge.stability/1``."""
    runs: list[StabilityRun]
    """Every run checked, in the order given."""
    configs: list[dict[str, Any]]
    """Per kind and candidate: the seed spread of the error, the worst seed, the runs that
    did not flatten."""
    families: list[dict[str, Any]]
    """Per family or failure case: the mean error and its ratio to the whole-set error."""
    settings: dict[str, str]
    """What each check is."""
