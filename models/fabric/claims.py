"""The woven-fabric paper's claims (Chen et al. 2024, Sec. 6) for ``report.pareto``
(:attr:`jobapi.reports.ReportFacts.claims` of ``train.fabric``): over ``score`` rows with
the fabric recipe's labels (``scripts/fabric_eval.yaml``), the network at 16 spp beats Monte
Carlo at equal time (``mc_eq``) and at 1 spp (``mc1``) on FLIP, per reference.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from jobapi.metric_names import matches, qualified
from jobapi.reports import CheckClaim
from jobapi.rows import ResultRow

#: The kind whose rows hold the recipe's renders scored against a reference.
SCORED_BY = "score"
#: The error the claims compare: FLIP of the rendered images (:mod:`jobapi.metric_names`).
FLIP = qualified("image", "flip")
#: The fabric recipe's labels (scripts/fabric_eval.yaml): network and its baselines.
FABRIC_NETWORK, FABRIC_BASELINES = "net16", (("mc_eq", "equal time"), ("mc1", "1 spp"))


def fabric_claims(rows: Sequence[ResultRow], check: CheckClaim) -> list[dict[str, Any]]:
    """Sec. 6 of the woven-fabric paper over the ``score`` rows among ``rows`` with the
    recipe's labels, each checked with ``check``."""
    scored = [r for r in rows if r.kind == SCORED_BY and matches(r.metric, FLIP)]
    datasets = sorted({r.dataset for r in scored if r.candidate == FABRIC_NETWORK and r.dataset})
    out = []
    for ds in datasets:
        for base, what in FABRIC_BASELINES:
            if any(r.candidate == base and r.dataset == ds for r in scored):
                out.append(
                    check(
                        scored,
                        {
                            "a": FABRIC_NETWORK,
                            "b": base,
                            "metric": FLIP,
                            "dataset": ds,
                            "claim": f"network (16 spp) FLIP < Monte Carlo at {what} against {ds}",
                        },
                    )
                )
    return out
