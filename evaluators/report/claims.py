"""The claims the model families make, checked over a report's rows: each kind's
:attr:`jobapi.reports.ReportFacts.claims` (e.g. the hybrid BRDF's in
:mod:`models.brdf.claims`, the woven fabric's in :mod:`models.fabric.claims`), in the
registry's order, each given :func:`evaluators.report.fronts.check_claim`. This module
knows no family: a kind's claims live with the kind.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from evaluators.report.fronts import check_claim
from jobapi.kinds import registered
from jobapi.rows import ResultRow


def family_claims(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """Every registered family's claims that the rows can speak to."""
    out: list[dict[str, Any]] = []
    for kind in registered().values():
        if kind.report is not None and kind.report.claims is not None:
            out += kind.report.claims(rows, check_claim)
    return out
