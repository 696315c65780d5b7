"""The numbers of ``report.brdf``: accuracy against cost, seed spread, families, claims.

Pure functions over :class:`Run` records (one finished ``train.brdf`` job each); no I/O, no
torch. A *configuration* is a model type and size: ``analytic``, ``hybrid 16x3``,
``neural 32x3``, with its latent size and per-material float count; its runs differ only in
their seed. Conventions (De Oliveira et al., hybrid neural-microfacet BRDF):

- accuracy: a run's mean SMAPE (Eq. 6) over its materials, from its ``metrics.json``; a
  configuration's accuracy is the mean over its seeds of that, with the sample standard
  deviation (``ddof = 1``; 0 for one seed) and the min and max;
- cost: ``ns_per_eval``, nanoseconds per BRDF evaluation of the fused Dr.Jit kernel
  (``fused_kernel_ns`` of the trained-size row of the runs' speed timings: kernel execution
  only, what a renderer pays per evaluation), the median over the configuration's runs
  that have one;
  the same name and meaning as the ``ns_per_eval`` cost of :mod:`jobapi.rows`;
- Pareto front: the configurations that no other configuration beats on both mean SMAPE and
  ns/eval (lower is better for both, at least one strictly);
- families: per family, the mean over seeds of the run's family mean SMAPE; the paper's
  Fig. 12 failure cases are singled out: ``iridescent`` (thin film) and ``blend``
  (multi-lobe).
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from evaluators.metrics.pareto import front_indices
from evaluators.metrics.pareto import spread as seed_spread
from models.brdf.fused import brdf_counts

#: Families the paper singles out (Fig. 12, Sec. 6): thin-film iridescence and multi-lobe.
HIGHLIGHT_FAMILIES: dict[str, str] = {
    "iridescent": "thin-film iridescence (Fig. 12 of the paper)",
    "blend": "multi-lobe blends (Fig. 12 of the paper)",
}
#: Sizes at which the paper's claim "hybrid no worse than neural" is checked first.
CLAIM_SIZES: tuple[str, ...] = ("16x3", "32x3")


@dataclass(frozen=True)
class Run:
    """One finished ``train.brdf`` job, reduced to what the report needs."""

    job_id: str
    seed: int
    model: str
    width: int
    depth: int
    latent_dim: int
    per_material_params: int
    materials: tuple[dict[str, Any], ...]  #: metrics.json rows: name, family, smape, mae
    speed: dict[str, Any] | None = None  #: the trained-size speed row, if any
    speed_source: str = "none"
    #: The run's own mean SMAPE (``metrics.json`` ``mean.smape``), read, never recomputed:
    #: a mean computed another way differs in the last bit (NOTES.md).
    stored_mean: float | None = None

    @property
    def size(self) -> str:
        return "-" if self.model == "analytic" else f"{self.width}x{self.depth}"

    @property
    def config(self) -> str:
        return "analytic" if self.model == "analytic" else f"{self.model} {self.size}"

    @property
    def mean_smape(self) -> float:
        """The run's mean SMAPE over its materials: the stored one when the run has it."""
        if self.stored_mean is not None:
            return self.stored_mean
        return float(statistics.fmean(r["smape"] for r in self.materials))

    def family_means(self) -> dict[str, float]:
        fams: dict[str, list[float]] = {}
        for r in self.materials:
            fams.setdefault(str(r["family"]), []).append(float(r["smape"]))
        return {f: statistics.fmean(v) for f, v in sorted(fams.items())}


@dataclass
class Config:
    """The runs of one configuration and their summary."""

    label: str
    runs: list[Run] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        first = self.runs[0]
        values = [r.mean_smape for r in self.runs]
        costs = [r.speed for r in self.runs if r.speed]
        kernel = [float(s["fused_kernel_ns"]) for s in costs]
        return {
            "config": self.label,
            "model": first.model,
            "size": first.size,
            "width": first.width,
            "depth": first.depth,
            "latent_dim": first.latent_dim,
            "per_material_params": first.per_material_params,
            "seeds": [r.seed for r in self.runs],
            "runs": [f"job:{r.job_id}" for r in self.runs],
            **spread(values),
            # One cost per meaning (issue 13): the plotted ns_per_eval is the kernel's own
            # time; the speed timings' fused_ns (tracing + launch + wait, per evaluation of one
            # batch) is another meaning and stays there and in the results table.
            "ns_per_eval": statistics.median(kernel) if kernel else None,
            "torch_ns": _median(costs, "torch_ns"),
            "bytes_per_network": costs[0].get("bytes_per_network") if costs else None,
            "bytes_per_material": 4 * first.per_material_params,
            # The costs that do not depend on the machine (models.counts).
            **brdf_counts(first.model, first.width, first.depth),
            "ns_source": sorted({r.speed_source for r in self.runs}),
        }


def _median(rows: Sequence[dict[str, Any]], key: str) -> float | None:
    vals = [float(r[key]) for r in rows if r.get(key) is not None]
    return statistics.median(vals) if vals else None


def spread(values: Sequence[float]) -> dict[str, float | int]:
    """``{"n", "smape_mean", "smape_std", "smape_min", "smape_max"}`` of per-seed values:
    :func:`evaluators.metrics.pareto.spread` with the statistics named for SMAPE."""
    return {k if k == "n" else f"smape_{k}": v for k, v in seed_spread(values).items()}


def group(runs: Sequence[Run]) -> dict[str, Config]:
    """Runs by configuration, in a stable order (analytic, hybrid, neural; by size)."""
    order = {"analytic": 0, "hybrid": 1, "neural": 2}
    configs: dict[str, Config] = {}
    for run in sorted(runs, key=lambda r: (order.get(r.model, 9), r.width, r.depth, r.seed)):
        key = run.config
        if key in configs and configs[key].runs[0].per_material_params != run.per_material_params:
            key = f"{key} ({run.per_material_params} floats)"
        configs.setdefault(key, Config(key)).runs.append(run)
    return configs


def pareto_front(points: Sequence[dict[str, Any]]) -> list[str]:
    """Labels of the non-dominated points (``ns_per_eval``, ``smape_mean``), by cost
    (:func:`evaluators.metrics.pareto.front_indices`)."""
    timed = [p for p in points if p.get("ns_per_eval") is not None]
    idx = front_indices([p["ns_per_eval"] for p in timed], [p["smape_mean"] for p in timed])
    return [timed[i]["config"] for i in idx]


def _paired(a: Config, b: Config) -> dict[str, Any]:
    """Per-seed comparison of ``a`` against ``b`` over the seeds both have."""
    sa = {r.seed: r.mean_smape for r in a.runs}
    sb = {r.seed: r.mean_smape for r in b.runs}
    seeds = sorted(set(sa) & set(sb))
    return {
        "seeds": seeds,
        "a_better_or_equal_on": sum(sa[s] <= sb[s] for s in seeds),
        "per_seed": {str(s): [sa[s], sb[s]] for s in seeds},
    }


def claims(configs: dict[str, Config]) -> list[dict[str, Any]]:
    """The paper's headline claims, computed from the runs, true or false as they come out.

    1. each hybrid size has a lower mean SMAPE than the analytic model (Fig. 4);
    2. at each size with both, the hybrid is no worse than the neural baseline with the same
       per-material float count (Table 1); sizes :data:`CLAIM_SIZES` first. A claim whose
       configurations are missing is listed with ``holds: null``.
    """
    out: list[dict[str, Any]] = []
    by_model: dict[str, dict[str, Config]] = {}
    for c in configs.values():
        by_model.setdefault(c.runs[0].model, {})[c.runs[0].size] = c
    analytic = by_model.get("analytic", {}).get("-")
    hybrids = by_model.get("hybrid", {})
    neurals = by_model.get("neural", {})
    for size, hyb in sorted(hybrids.items()):
        claim: dict[str, Any] = {"claim": f"hybrid {size} mean SMAPE < analytic"}
        if analytic is None:
            out.append({**claim, "holds": None, "why": "no analytic run in the report"})
            continue
        h, a = (statistics.fmean(r.mean_smape for r in c.runs) for c in (hyb, analytic))
        out.append({**claim, "holds": h < a, "hybrid": h, "analytic": a,
                    "paired": _paired(hyb, analytic)})  # fmt: skip
    sizes = list(CLAIM_SIZES)  # always listed, null where a configuration is missing
    sizes += sorted((set(hybrids) & set(neurals)) - set(sizes))
    for size in sizes:
        claim = {"claim": f"hybrid {size} mean SMAPE <= neural {size} at equal per-material "
                 "parameters"}  # fmt: skip
        maybe_h, maybe_n = hybrids.get(size), neurals.get(size)
        if maybe_h is None or maybe_n is None:
            missing = "hybrid" if maybe_h is None else "neural"
            out.append({**claim, "holds": None, "why": f"no {missing} {size} run in the report"})
            continue
        ph, pn = maybe_h.runs[0].per_material_params, maybe_n.runs[0].per_material_params
        h, n = (statistics.fmean(r.mean_smape for r in c.runs) for c in (maybe_h, maybe_n))
        row = {**claim, "hybrid": h, "neural": n, "per_material_params": [ph, pn],
               "paired": _paired(maybe_h, maybe_n)}  # fmt: skip
        if ph != pn:
            out.append({**row, "holds": None, "why": f"per-material floats differ: {ph} vs {pn}"})
        else:
            out.append({**row, "holds": h <= n})
    return out


def families(configs: dict[str, Config]) -> dict[str, Any]:
    """``families.json``: per configuration and family, the spread over seeds of the
    family's mean SMAPE; the highlighted families first."""
    names = sorted({f for c in configs.values() for r in c.runs for f in r.family_means()})
    names = [f for f in HIGHLIGHT_FAMILIES if f in names] + [
        f for f in names if f not in HIGHLIGHT_FAMILIES
    ]
    table: dict[str, dict[str, Any]] = {}
    for label, c in configs.items():
        per = [r.family_means() for r in c.runs]
        table[label] = {
            f: {**spread([p[f] for p in per if f in p]), "materials": _count(c, f)}
            for f in names
            if any(f in p for p in per)
        }
    worst = {label: max(rows, key=lambda f: rows[f]["smape_mean"]) for label, rows in table.items()}
    return {
        "families": names,
        "highlight": {f: HIGHLIGHT_FAMILIES[f] for f in names if f in HIGHLIGHT_FAMILIES},
        "configs": table,
        "worst_family": worst,
    }


def _count(c: Config, family: str) -> int:
    return sum(1 for r in c.runs[0].materials if r["family"] == family)


#: SMAPE (Eq. 6, eps 0) lies in [0, 2]; 2 where one of the two values is 0.
SMAPE_MAX = 2.0
#: A material whose SMAPE is at least this fraction of the maximum is flagged: its score
#: says nothing about which model is better (both miss everything, or the table is empty
#: where the model is not), and a mean over materials hides it.
NEAR_MAX_FRACTION = 0.9


def near_maximum(configs: dict[str, Config]) -> list[dict[str, Any]]:
    """The materials whose mean SMAPE over a configuration's seeds is within 10 % of the
    metric's maximum 2, in any configuration: ``[{"material", "family", "smape": {config:
    mean}, "maximum": 2, "warning"}]``, worst first. ``report.brdf`` adds each as a claim
    that does not hold (``pareto.json``'s ``claims``, its result table and its last progress
    line), so that a saturated material is never silent."""
    per: dict[str, dict[str, list[float]]] = {}
    family: dict[str, str] = {}
    for c in configs.values():
        for run in c.runs:
            for m in run.materials:
                name = str(m["name"])
                family[name] = str(m.get("family", ""))
                per.setdefault(name, {}).setdefault(c.label, []).append(float(m["smape"]))
    out = []
    for name, by_config in per.items():
        means = {label: statistics.fmean(v) for label, v in by_config.items()}
        if max(means.values()) >= NEAR_MAX_FRACTION * SMAPE_MAX:
            worst = ", ".join(f"{k} {v:.3f}" for k, v in means.items())
            out.append(
                {
                    "material": name,
                    "family": family[name],
                    "smape": means,
                    "maximum": SMAPE_MAX,
                    "warning": f"{name}: SMAPE near its maximum {SMAPE_MAX:g} ({worst}): the "
                    "score cannot rank models on this material",
                }
            )
    return sorted(out, key=lambda d: -max(d["smape"].values()))
