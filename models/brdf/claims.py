"""The hybrid-BRDF paper's claims (De Oliveira et al.) over ``train.brdf`` result rows, for
``report.pareto`` (:attr:`jobapi.reports.ReportFacts.claims` of ``train.brdf``):

- each hybrid size has a lower mean SMAPE than the analytic model (Fig. 4);
- at each size with both, the hybrid is no worse than the neural baseline at equal
  per-material floats (Table 1): ``holds`` is ``None``, with a reason, where the float counts
  differ.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from jobapi.metric_names import qualified
from jobapi.reports import CheckClaim
from jobapi.rows import ResultRow

#: The error the claims compare (:mod:`jobapi.metric_names`).
SMAPE = qualified("brdf", "smape")
#: This module's kind: only its rows are read.
KIND = "train.brdf"
_SIZE = re.compile(r"^(?P<model>hybrid|neural) (?P<size>\d+x\d+)$")


def _floats(rows: Sequence[ResultRow], candidate: str) -> set[Any]:
    return {r.config.get("per_material_params") for r in rows if r.candidate == candidate}


def brdf_claims(rows: Sequence[ResultRow], check: CheckClaim) -> list[dict[str, Any]]:
    """The claims (see the module docstring) over the ``train.brdf`` rows among ``rows``,
    each checked with ``check``."""
    brdf = [r for r in rows if r.kind == KIND]
    sizes: dict[str, set[str]] = {"hybrid": set(), "neural": set()}
    for r in brdf:
        m = _SIZE.match(r.candidate or "")
        if m:
            sizes[m["model"]].add(m["size"])
    out = []
    for size in sorted(sizes["hybrid"]):
        out.append(
            check(
                brdf,
                {
                    "a": f"hybrid {size}",
                    "b": "analytic",
                    "metric": SMAPE,
                    "claim": f"hybrid {size} mean SMAPE < analytic",
                },
            )
        )
    for size in sorted(sizes["hybrid"] & sizes["neural"]):
        h, n = f"hybrid {size}", f"neural {size}"
        claim = check(
            brdf,
            {
                "a": h,
                "b": n,
                "metric": SMAPE,
                "relation": "<=",
                "claim": f"{h} mean SMAPE <= {n} at equal per-material parameters",
            },
        )
        fh, fn = _floats(brdf, h), _floats(brdf, n)
        if fh != fn:
            claim = {
                **claim,
                "holds": None,
                "why": f"per-material floats differ: {sorted(fh)} vs {sorted(fn)}",
            }
        out.append(claim)
    return out
