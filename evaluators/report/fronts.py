"""The numbers of ``report.pareto``: error-against-cost panels, families and claims, from
result rows (:class:`jobapi.rows.ResultRow`). Pure functions; no I/O.

- A *panel* is one dataset, scene, error metric and cost column. Its *points* are the
  candidates (``"hybrid 32x3"``, ``"net16"``, ``"mc1"``): all rows of one candidate in the
  panel, whole-set rows only (``material`` empty or ``"mean"``; of a job with a ``test``
  split, its test rows: :func:`jobapi.rows.headline_rows`), are its repeated
  measurements, one per job (seed); the point's error is their mean, with the sample std and
  the min and max over seeds (the error bars), and its cost the median of the rows' costs.
- The front (:func:`evaluators.metrics.pareto.front_indices`) is taken on (cost, mean
  error); every point records which points dominate it.
- With a timing pass (:mod:`evaluators.report.timing`), an ``ns_per_eval`` panel's costs
  are the pass's, not the rows': each point's median with ``cost_min``, ``cost_max``,
  ``cost_iqr``, ``cost_n`` and ``relative`` (its ratio to the reference kernel).
- Resolution: each point is ``resolved`` when its place on or off the front holds
  anywhere inside its spreads (:func:`box`: seed min..max on the error where there are two
  or more seeds, timing min..max on the cost), else ``tied_with`` names the points that
  make it undecided (:func:`evaluators.metrics.pareto.unresolved_with`); a panel lists its
  ``ties`` and says why it is ``not_resolved``. A panel of a cost each job timed itself
  (``render_seconds``, ``train_seconds``, ``ms_per_frame``) is charted but never resolved:
  those costs come from separate passes.
- Every point names its ``split``: ``test`` where its runs' errors are over held-out data,
  ``train`` where over the data they were fitted to, ``null`` for neither (a score of
  renders); the chart labels the points with it.
- Every point names its ``runtime`` (:data:`jobapi.rows.RUNTIMES`: what evaluated it, the
  rows' ``runtime`` joined with ``+`` when they differ, ``null`` when none says), and a panel
  lists its ``runtimes``: a chart of ``ns_per_eval`` whose points come from two runtimes
  says so on the axis (:func:`cost_label`), so it never hides it.
- *Families*: per dataset, metric and candidate, the per-material rows grouped by
  ``family`` (MERL family, fabric pattern): mean over the family's materials per job,
  then the spread over jobs.
- *Claims*: ``{"a", "b", "metric", "relation"}`` compare two candidates' mean error over
  every whole-set row of that metric (optionally one dataset); each comes back with
  ``holds`` true / false and the numbers, or ``null`` with ``why``. The seed spread decides:
  where both candidates have rows from at least two jobs (seeds), each job's mean is one
  repeat, and a claim whose two ranges of per-job means (min..max) overlap is *not
  resolved* (``holds: null``, ``resolved: false``): its difference is inside the spread.
  With one job on a side there is no spread to judge by; the verdict is the means' and
  ``resolved`` is ``null`` ("one seed" in ``why``).
"""

from __future__ import annotations

import statistics
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from evaluators.metrics.pareto import dominated_by, front_indices, spread, unresolved_with
from jobapi.metric_names import matches, qualified
from jobapi.rows import ResultRow, headline_rows, whole_set

#: Error metrics charted when none are asked for, in this order (those present).
DEFAULT_ERRORS = (
    qualified("brdf", "smape"),
    qualified("image", "flip"),
    qualified("image", "flip_mean"),
    "l1",
    "rgb.rel",
    qualified("brdf", "mae"),
    qualified("image", "mae"),
)
#: Cost columns charted when none are asked for, in this order (those present).
DEFAULT_COSTS = ("ns_per_eval", "bytes_per_material", "ms_per_frame", "render_seconds", "spp")
#: Axis labels of the cost columns: the column's name, then what it measures.
COST_LABELS = {
    "ns_per_eval": "ns_per_eval: ns per evaluation on a fixed batch, in each point's runtime",
    "bytes_per_material": "bytes_per_material: float32 parameters per material",
    "bytes_per_network": "bytes_per_network: float32 network weights",
    "ms_per_frame": "ms_per_frame: kernel ms per displayed frame",
    "render_seconds": "render_seconds: seconds of the render's passes, without JIT compilation",
    "spp": "spp: samples per pixel",
    "train_seconds": "train_seconds: wall seconds of the training job",
    "macs_per_eval": "macs_per_eval: multiply-adds per evaluation (any machine)",
    "bytes_per_eval": "bytes_per_eval: bytes read per evaluation (any machine)",
}
RELATIONS = ("<", "<=")


def error_metrics(rows: Iterable[ResultRow], asked: Sequence[str] | None) -> list[str]:
    """``asked``, or the :data:`DEFAULT_ERRORS` present in ``rows``."""
    if asked:
        return list(asked)
    present = {r.metric for r in rows}
    return [m for m in DEFAULT_ERRORS if m in present]


def cost_columns(rows: Iterable[ResultRow], asked: Sequence[str] | None) -> list[str]:
    """``asked``, or the :data:`DEFAULT_COSTS` that some row has."""
    if asked:
        return list(asked)
    rows = list(rows)
    return [c for c in DEFAULT_COSTS if any(getattr(r, c) is not None for r in rows)]


def runtime_of(rows: Iterable[ResultRow]) -> str | None:
    """The runtimes of ``rows``, sorted and joined with ``+``; ``None`` when none names one."""
    names = sorted({r.runtime for r in rows if r.runtime})
    return "+".join(names) if names else None


def cost_label(cost: str, runtimes: Sequence[str]) -> str:
    """The axis label of ``cost``; with points from more than one runtime, it names them."""
    label = COST_LABELS.get(cost, cost)
    if len(runtimes) > 1:
        label += f" [runtimes differ: {', '.join(runtimes)}]"
    return label


def _point(
    candidate: str, rows: list[ResultRow], cost: str, timed: Mapping[str, Any] | None
) -> dict[str, Any] | None:
    by_job: dict[str, list[float]] = defaultdict(list)
    costs = [float(getattr(r, cost)) for r in rows if getattr(r, cost) is not None]
    if timed is not None:
        costs = [float(timed["cost"])]  # the pass's, whether or not the job timed itself
    if not costs:
        return None
    seeds = {}
    for r in rows:
        by_job[r.job].append(r.value)
        seeds[r.job] = r.seed
    per_job = [statistics.fmean(v) for v in by_job.values()]
    s = spread(per_job)
    point: dict[str, Any] = {
        "candidate": candidate,
        **s,
        "cost": statistics.median(costs),
        "jobs": [f"job:{j}" for j in by_job],
        "seeds": [seeds[j] for j in by_job],
        "per_seed": per_job,
        "kind": rows[0].kind,
        "runtime": runtime_of(rows),
        "split": "+".join(sorted({r.split for r in rows if r.split})) or None,
    }
    if timed is not None:  # the comparison's own timing pass replaces the rows' costs
        point.update({k: v for k, v in timed.items() if k not in ("macs_per_eval",
                      "bytes_per_eval") or v is not None})  # fmt: skip
    return point


def box(point: Mapping[str, Any]) -> tuple[float, float, float, float]:
    """A point's spread ``(cost_lo, cost_hi, error_lo, error_hi)``: its timing pass's min and
    max cost (else its cost), its min and max error over two or more seeds (else its mean)."""
    c_lo = float(point.get("cost_min", point["cost"]))
    c_hi = float(point.get("cost_max", point["cost"]))
    seeded = int(point.get("n") or 1) >= 2 and point.get("min") is not None
    e_lo = float(point["min"]) if seeded else float(point["mean"])
    e_hi = float(point["max"]) if seeded else float(point["mean"])
    return (c_lo, c_hi, e_lo, e_hi)


def resolve_front(points: list[dict[str, Any]], front: Sequence[int]) -> dict[str, Any]:
    """Mark each point ``resolved`` (its place on or off the front holds anywhere in the
    spreads) and name its ``tied_with``; return the panel's ``resolved`` and ``ties``
    (:func:`evaluators.metrics.pareto.unresolved_with`)."""
    ties = unresolved_with([box(p) for p in points], front)
    pairs: list[list[str]] = []
    for p, tie in zip(points, ties, strict=True):
        p["resolved"] = not tie
        p["tied_with"] = [points[j]["candidate"] for j in tie]
        for q in p["tied_with"]:
            pair = sorted((p["candidate"], q))
            if pair not in pairs:
                pairs.append(pair)
    return {"resolved": not pairs, "ties": pairs}


def _not_resolved(cost: str, ties: list[list[str]], job_timed: bool) -> str | None:
    parts = []
    if job_timed:
        parts.append(
            f"{cost} is each job's own timing, taken in separate passes: the cost axis "
            "is not ranked (ns_per_eval is re-timed in one pass)"
        )
    if ties:
        parts.append("inside the spread: " + "; ".join(" and ".join(t) for t in ties))
    return "not resolved: " + "; ".join(parts) if parts else None


def panels(
    rows: Sequence[ResultRow],
    metrics: Sequence[str],
    costs: Sequence[str],
    timing: Mapping[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """One panel per (dataset, scene, metric, cost) with at least one costed point, in the
    order of first appearance; see the module docstring. ``timing``: the comparison's
    timing pass (:func:`evaluators.report.timing.comparison_pass`), whose costs replace the
    rows' ``ns_per_eval``."""
    from evaluators.report.timing import JOB_TIMED_COSTS, PASS_COSTS, pass_cost

    groups: dict[tuple[Any, ...], dict[str, list[ResultRow]]] = {}
    for r in headline_rows(rows):
        if matches(r.metric, metrics) and r.candidate is not None:
            for cost in costs:
                key = (r.dataset, r.scene, r.metric, cost)
                groups.setdefault(key, {}).setdefault(r.candidate, []).append(r)
    out = []
    for (dataset, scene, metric, cost), by_cand in groups.items():
        timed = timing is not None and cost in PASS_COSTS
        points = []
        for c, rs in by_cand.items():
            got = pass_cost(timing, c) if timed and timing is not None else None
            if timed and got is None:
                continue  # not timed in the pass: never charted beside its costs
            if (p := _point(c, rs, cost, got)) is not None:
                points.append(p)
        if not points:
            continue
        xs, ys = [p["cost"] for p in points], [p["mean"] for p in points]
        on = front_indices(xs, ys)
        beaten = dominated_by(xs, ys)
        for i, p in enumerate(points):
            p["front"] = i in on
            p["dominated_by"] = [points[j]["candidate"] for j in beaten[i]]
        decided = resolve_front(points, on)
        job_timed = cost in JOB_TIMED_COSTS and len(points) > 1
        runtimes = sorted({p["runtime"] for p in points if p["runtime"]})
        label = cost_label(cost, runtimes)
        if timed and timing is not None:
            clock = "CPU time" if timing.get("clock") == "cpu" else "wall time"
            label += f" (one timing pass, {clock}, bars min..max)"
        elif job_timed:
            label += " [timed in separate jobs: not ranked]"
        out.append(
            {
                "dataset": dataset,
                "scene": scene,
                "metric": metric,
                "cost": cost,
                "cost_label": label,
                "runtimes": runtimes,
                "points": points,
                "front": [points[i]["candidate"] for i in on],
                "resolved": decided["resolved"] and not job_timed,
                "ties": decided["ties"],
                "not_resolved": _not_resolved(cost, decided["ties"], job_timed),
                "timing_pass": bool(timed),
                "job_timed": job_timed,
            }
        )
    return out


def families(rows: Sequence[ResultRow], metrics: Sequence[str]) -> list[dict[str, Any]]:
    """Per dataset, metric, candidate and family: the spread over jobs of the family's mean
    over its materials."""
    acc: dict[tuple[Any, ...], dict[str, list[float]]] = {}
    for r in rows:
        if matches(r.metric, metrics) and not whole_set(r) and r.family and r.candidate is not None:
            key = (r.dataset, r.metric, r.candidate, r.family)
            acc.setdefault(key, {}).setdefault(r.job, []).append(r.value)
    out = []
    for (dataset, metric, candidate, family), by_job in acc.items():
        per_job = [statistics.fmean(v) for v in by_job.values()]
        out.append(
            {
                "dataset": dataset,
                "metric": metric,
                "candidate": candidate,
                "family": family,
                "materials": len(next(iter(by_job.values()))),
                **spread(per_job),
            }
        )
    return out


def check_claim(rows: Sequence[ResultRow], claim: Mapping[str, Any]) -> dict[str, Any]:
    """One claim ``{"a", "b", "metric", "relation" ("<" or "<="), "dataset"?, "claim"?}``:
    ``a``'s mean error against ``b``'s over their whole-set rows of ``metric``."""
    a, b, metric = str(claim["a"]), str(claim["b"]), str(claim["metric"])
    rel = str(claim.get("relation", "<"))
    if rel not in RELATIONS:
        raise ValueError(f"claim relation {rel!r}: use one of {', '.join(RELATIONS)}")
    text = str(claim.get("claim") or f"{a} {metric} {rel} {b} {metric}")
    dataset = claim.get("dataset")
    out: dict[str, Any] = {"claim": text, "a": a, "b": b, "metric": metric, "relation": rel}

    headline = headline_rows(rows)

    def values(cand: str) -> list[float]:
        return [
            r.value
            for r in headline
            if r.candidate == cand
            and matches(r.metric, metric)
            and (dataset is None or r.dataset == dataset)
        ]

    def per_job(cand: str) -> list[float]:
        by: dict[str, list[float]] = defaultdict(list)
        for r in headline:
            if (
                r.candidate == cand
                and matches(r.metric, metric)
                and (dataset is None or r.dataset == dataset)
            ):
                by[r.job].append(r.value)
        return [statistics.fmean(v) for v in by.values()]

    va, vb = values(a), values(b)
    missing = [c for c, v in ((a, va), (b, vb)) if not v]
    if missing:
        return {**out, "holds": None, "why": f"no {metric} rows of {', '.join(missing)}"}
    ma, mb = statistics.fmean(va), statistics.fmean(vb)
    ja, jb = per_job(a), per_job(b)
    numbers = {
        "a_mean": ma,
        "b_mean": mb,
        "a_n": len(va),
        "b_n": len(vb),
        "a_seeds": len(ja),
        "b_seeds": len(jb),
        "a_range": [min(ja), max(ja)],
        "b_range": [min(jb), max(jb)],
    }
    holds: bool | None = ma < mb if rel == "<" else ma <= mb
    resolved: bool | None = None
    spread_note = "; one seed on a side: no spread to judge by"
    if len(ja) >= 2 and len(jb) >= 2:
        resolved = max(ja) < min(jb) or min(ja) > max(jb)
        spread_note = (
            f"; seed ranges {min(ja):.4g}..{max(ja):.4g} and {min(jb):.4g}..{max(jb):.4g}"
            + ("" if resolved else " overlap: not resolved")
        )
        if not resolved:
            holds = None
    verb = "?" if holds is None else "" if holds else "not "
    why = (
        f"{a}: {ma:.4g} (mean of {len(va)}) {verb}{rel} "
        f"{b}: {mb:.4g} (mean of {len(vb)}){spread_note}"
    )
    return {**out, "holds": holds, "resolved": resolved, "why": why, **numbers}
