"""The claims a model family makes, as :func:`evaluators.report.fronts.check_claim` specs,
found from the candidates present in a report's rows.

- BRDF (De Oliveira et al.; ``train.brdf`` rows): each hybrid size has a lower mean SMAPE
  than the analytic model (Fig. 4); at each size with both, the hybrid is no worse than the
  neural baseline at equal per-material floats (Table 1): ``null`` with a reason where the
  float counts differ.
- Woven fabric (Chen et al. 2024, Sec. 6; ``score`` rows of the fabric recipe's labels):
  the network at 16 spp beats Monte Carlo at equal time (``mc_eq``) and at 1 spp (``mc1``)
  on FLIP, per reference.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from evaluators.report.fronts import check_claim
from jobapi.rows import ResultRow

_SIZE = re.compile(r"^(?P<model>hybrid|neural) (?P<size>\d+x\d+)$")
#: The fabric recipe's labels (scripts/fabric_eval.yaml): network and its baselines.
FABRIC_NETWORK, FABRIC_BASELINES = "net16", (("mc_eq", "equal time"), ("mc1", "1 spp"))


def _floats(rows: Sequence[ResultRow], candidate: str) -> set[Any]:
    return {r.config.get("per_material_params") for r in rows if r.candidate == candidate}


def brdf_claims(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """The hybrid-BRDF paper's claims over ``train.brdf`` rows (see the module docstring)."""
    brdf = [r for r in rows if r.kind == "train.brdf"]
    sizes: dict[str, set[str]] = {"hybrid": set(), "neural": set()}
    for r in brdf:
        m = _SIZE.match(r.candidate or "")
        if m:
            sizes[m["model"]].add(m["size"])
    out = []
    for size in sorted(sizes["hybrid"]):
        out.append(
            check_claim(
                brdf,
                {
                    "a": f"hybrid {size}",
                    "b": "analytic",
                    "metric": "smape",
                    "claim": f"hybrid {size} mean SMAPE < analytic",
                },
            )
        )
    for size in sorted(sizes["hybrid"] & sizes["neural"]):
        h, n = f"hybrid {size}", f"neural {size}"
        claim = check_claim(
            brdf,
            {
                "a": h,
                "b": n,
                "metric": "smape",
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


def fabric_claims(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """Sec. 6 of the woven-fabric paper over ``score`` rows with the recipe's labels."""
    scored = [r for r in rows if r.kind == "score" and r.metric == "flip"]
    datasets = sorted({r.dataset for r in scored if r.candidate == FABRIC_NETWORK and r.dataset})
    out = []
    for ds in datasets:
        for base, what in FABRIC_BASELINES:
            if any(r.candidate == base and r.dataset == ds for r in scored):
                out.append(
                    check_claim(
                        scored,
                        {
                            "a": FABRIC_NETWORK,
                            "b": base,
                            "metric": "flip",
                            "dataset": ds,
                            "claim": f"network (16 spp) FLIP < Monte Carlo at {what} against {ds}",
                        },
                    )
                )
    return out


def family_claims(rows: Sequence[ResultRow]) -> list[dict[str, Any]]:
    """Every family's claims that the rows can speak to."""
    return brdf_claims(rows) + fabric_claims(rows)
