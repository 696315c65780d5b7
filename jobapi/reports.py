"""What report kinds need to know of the kinds whose jobs they read, declared by those kinds.

``report.stability`` and ``report.pareto`` read other jobs' result rows (:mod:`jobapi.rows`).
What those rows mean is the knowledge of the kind that wrote them: which metric is its
headline error, which candidate its rows are about, which metric compares its failure
cases, where its training loss is in ``curves.json``, what checks its model needs, and which
claims its paper makes. A kind declares them on its :class:`~jobapi.kinds.Kind` as
``report=ReportFacts(...)``; the report code asks the registry and never names a kind::

    register(Kind(name="train.mine", ..., report=ReportFacts(metric="l1")))

A kind without ``report`` is not a training kind to ``report.stability`` (its jobs are
refused there), and adds no claims to ``report.pareto``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from jobapi.documents import CurvesDocument, read_typed
from jobapi.rows import ResultRow

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: ``loss(curves)``: the training loss per logged step of a parsed ``curves.json`` (or of
#: ``None``, or anything else a job may have written: then ``[]``).
LossHook = Callable[[Any], list[float | None]]
#: ``checks(ctx, job_id)``: checks of the model a finished training job wrote (read through
#: ``ctx``), as fields added to its run in ``stability.json``; raises
#: :class:`~jobapi.errors.JobFailed` when the model does not load.
ChecksHook = Callable[["JobContext", str], dict[str, Any]]
#: ``check(rows, spec)``: one claim checked over rows (``report.pareto``'s
#: :func:`evaluators.report.fronts.check_claim`): the spec with ``holds`` and ``why``.
CheckClaim = Callable[[Sequence[ResultRow], Mapping[str, Any]], dict[str, Any]]
#: ``claims(rows, check)``: the claims a family's paper makes that ``rows`` can speak to,
#: each checked with ``check`` (the rows may be of any kinds: pick your own).
ClaimsHook = Callable[[Sequence[ResultRow], CheckClaim], list[dict[str, Any]]]


def phase_loss(curves: Any, key: str = "loss") -> list[float | None]:
    """The ``key`` series of a ``curves.json`` document of the one schema
    (:class:`jobapi.documents.CurvesDocument`), cut to its ``train`` phase when it has
    ``phases`` (a held-out phase fits other data); ``[]`` when there is no such series."""
    doc = read_typed(curves, CurvesDocument)
    if doc is None:
        return []
    values = doc.get(key)  # a series: an extra key of the type, checked by its rules
    if not isinstance(values, list):
        return []
    span = next((p for p in doc.get("phases", []) if p["name"] == "train"), None)
    if span is not None:
        return [
            v
            for s, v in zip(doc["step"], values, strict=True)
            if span["first_step"] <= s <= span["last_step"]
        ]
    return list(values)


@dataclass(frozen=True)
class ReportFacts:
    """What the report kinds read of a training kind's jobs.

    Attributes:
        metric: the headline error of its result rows (lower is better), e.g. ``"smape"``:
            the row of that metric without a material (or with material ``"mean"``) is a
            run's whole-set error.
        candidate: only rows of this candidate are its headline (``None``: any), e.g.
            ``"network"`` where a job also rows its baselines.
        family_metric: the metric its failure cases (row ``family``) are compared by, when
            not :attr:`metric` (a relative error where the cases' scales differ).
        loss_key: the ``curves.json`` series that is its training loss.
        loss: reads the training loss itself (:data:`LossHook`), for documents older than
            the one schema; ``None``: :func:`phase_loss` of :attr:`loss_key`.
        checks: checks of its trained model (:data:`ChecksHook`), run by
            ``report.stability`` when its ``model_checks`` is on.
        claims: its paper's claims (:data:`ClaimsHook`), checked by ``report.pareto``.
    """

    metric: str
    candidate: str | None = None
    family_metric: str | None = None
    loss_key: str = "loss"
    loss: LossHook | None = None
    checks: ChecksHook | None = None
    claims: ClaimsHook | None = None

    @property
    def families_by(self) -> str:
        """The metric its failure cases are compared by."""
        return self.family_metric or self.metric

    def training_loss(self, curves: Any) -> list[float | None]:
        """Its training loss from a parsed ``curves.json`` (``[]`` when there is none)."""
        return self.loss(curves) if self.loss is not None else phase_loss(curves, self.loss_key)
