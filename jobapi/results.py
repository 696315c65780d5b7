"""Result tables: what a kind's summary hook returns, and what the edges show.

A kind knows its own artifacts; the dashboard, the CLI's batch table and
``GET /api/jobs/{id}/summary`` know none of them. Each asks the kind's summary hook
(:attr:`jobapi.kinds.Kind.summary`) for a :class:`ResultTable`: rows by label (a candidate,
a material, a configuration), named columns, and optional context (the reference, the
settings used, claims that hold or not).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

#: ``read(name)``: the JSON artifact ``name`` of a job, parsed, or ``None`` when the job has
#: no such artifact or it is too large or unreadable.
ArtifactReader = Callable[[str], Any]


@dataclass(frozen=True)
class ResultTable:
    """A table of a job's results.

    Attributes:
        title: what the table shows, e.g. ``"Metrics per material"``.
        label_header: the header of the label column, e.g. ``"Candidate"``.
        columns: the value columns, in order.
        rows: ``{label: {column: value}}``; a value is a number, a string, a bool or
            ``None`` (shown as missing).
        reference: what the rows were compared against, when there is one.
        settings: the settings the values were computed with (shown as JSON).
        claims: ``[{"claim": str, "holds": bool, ...}]`` checked by the job.
        ranked: whether its rows compete (candidates, configurations, a model's
            materials): the dashboard marks each column's best row. ``False`` for rows that
            are a dataset's items, measured rather than scored (a MERL collection's table
            quality, a fabric dataset's materials): none is "the best".
    """

    title: str
    label_header: str
    columns: list[str]
    rows: dict[str, dict[str, Any]]
    reference: str | None = None
    settings: Any = None
    claims: list[dict[str, Any]] = field(default_factory=list)
    ranked: bool = True

    def document(self) -> dict[str, Any]:
        """The JSON form (``GET /api/jobs/{id}/summary``, the dashboard's template)."""
        return {
            "title": self.title,
            "label_header": self.label_header,
            "labels": list(self.rows),
            "names": list(self.columns),
            "rows": self.rows,
            "reference": self.reference,
            "settings": self.settings,
            "claims": self.claims,
            "ranked": self.ranked,
        }

    @classmethod
    def from_document(cls, doc: Mapping[str, Any]) -> ResultTable:
        """The table back from its JSON form (:meth:`document`), e.g. as the REST API
        returned it; ``ValueError`` if ``doc`` is not one."""
        try:
            rows = {str(k): dict(v) for k, v in doc["rows"].items()}
            return cls(
                title=str(doc["title"]),
                label_header=str(doc["label_header"]),
                columns=[str(c) for c in doc["names"]],
                rows=rows,
                reference=doc.get("reference"),
                settings=doc.get("settings"),
                claims=list(doc.get("claims") or []),
                ranked=bool(doc.get("ranked", True)),
            )
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a result table document ({exc})") from None

    @classmethod
    def from_report(
        cls,
        doc: Mapping[str, Any],
        rows: dict[str, dict[str, Any]],
        *,
        title: str,
        label_header: str,
        columns: Sequence[str],
    ) -> ResultTable:
        """The table of a report job: ``rows`` with the ``settings`` and the well-formed
        ``claims`` (``{"claim": ...}`` objects) of its document ``doc`` (``pareto.json``)."""
        claims = [c for c in doc.get("claims") or [] if isinstance(c, dict) and "claim" in c]
        return cls(
            title=title,
            label_header=label_header,
            columns=list(columns),
            rows=rows,
            settings=doc.get("settings"),
            claims=claims,
        )

    def flat(self) -> dict[str, float]:
        """Numeric cells as ``{"<label>.<column>": value}`` (bools and text left out), in
        row then column order: the columns of a batch's results file."""
        out: dict[str, float] = {}
        for label, row in self.rows.items():
            for col in self.columns:
                value = row.get(col)
                if isinstance(value, int | float) and not isinstance(value, bool):
                    out[f"{label}.{col}"] = float(value)
        return out


def flatten(doc: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested values as dotted keys: ``{"rgb": {"rel": x}}`` -> ``{"rgb.rel": x}``."""
    out: dict[str, Any] = {}
    for key, value in doc.items():
        if isinstance(value, Mapping):
            out.update(flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def used_columns(columns: Iterable[str], rows: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The ``columns`` that have a value in at least one row, in order."""
    return [c for c in columns if any(r.get(c) is not None for r in rows.values())]


def per_material_table(
    doc: Any, columns: Iterable[str], *, title: str = "Metrics per material"
) -> ResultTable | None:
    """The table of a training job's ``metrics.json``: ``{"materials": [{"name", ...}],
    "mean": {...}, "settings": {...}}``, one row per material then ``mean``, nested values
    flattened (``rgb.rel``), only the ``columns`` that have values."""
    if not isinstance(doc, Mapping) or not isinstance(doc.get("materials"), list):
        return None
    mats = [m for m in doc["materials"] if isinstance(m, Mapping) and "name" in m]
    if not mats:
        return None
    cols = list(columns)
    rows = {str(m["name"]): {k: flatten(m).get(k) for k in cols} for m in mats}
    if isinstance(doc.get("mean"), Mapping):
        rows["mean"] = {k: flatten(doc["mean"]).get(k) for k in cols}
    return ResultTable(
        title=title,
        label_header="Material",
        columns=used_columns(cols, rows),
        rows=rows,
        settings=doc.get("settings"),
    )
