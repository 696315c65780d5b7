"""The ``select`` job kind: the cheapest candidate that meets a quality target.

Model no more than a scene needs. ``runs`` hold the measured ladder: e.g. the fabric
recipe's score jobs (Monte Carlo at 1 and 6 spp, the network at 1 and 16 spp, each FLIP
against the 256-spp reference) or ``train.brdf`` runs (analytic, hybrid 16x3, 32x3). Per
dataset and scene (one reference), the rungs are the candidates ordered by ``cost``, each at
its mean ``metric`` over seeds (:func:`evaluators.report.fronts.panels`); the chosen rung is
the cheapest whose value meets ``target`` (``<=`` for an error, ``>=`` for a metric where
higher is better, e.g. PSNR), or none, with the reason.

Two modes, one of them per spec:

- ``runs``: choose among rungs that were already rendered and scored (a batch file makes
  them); nothing is rendered.
- ``scene`` + ``reference`` + ``ladder``: render every rung (and the reference, when it is
  given as a material) in the scene, as shards through the job's executor (process pool or
  Ray; a crashed job resumes from its finished renders), score each against the reference
  with :mod:`evaluators.metrics.images` as ``score`` does, measure its cost, and choose
  (:mod:`evaluators.report.select_scene`).

Artifacts: ``select.json`` (``ladders``: rungs with value, cost, ``meets``; ``chosen`` and
``why``; in the scene mode also ``mode: "scene"``, the scene, reference and ladder as given,
and per rung its spp, ``render_seconds``, ``frame_seconds``, integrator, material and
image), ``select.png``
(per ladder, the rungs' values as bars by increasing cost, the target as a line, the chosen
rung highlighted); in the scene mode also ``rung_<name>.exr`` / ``.png`` per rung,
``flip_<name>.png`` (the FLIP error map, for ``metric: flip``) and, for a rendered
reference, ``reference.exr`` / ``.png``. Result rows (``GET /api/results``,
``report.pareto``): in the scene mode one per rung, its metric against the rendered
reference with ``spp`` and ``render_seconds`` (and the model cost, if chosen by one).

Same spec, same bytes, with one declared exception (``timing_artifacts``): in the scene
mode the job times its own renders, and the rungs' ``render_seconds`` and
``frame_seconds`` are its product (listed per rung, and the cost the ladder may be ranked
and chosen by), so ``select.json`` varies between runs, and so does ``select.png`` when
``cost`` is one of those times (by ``spp`` or a model's cost the choice and the plot do
not). The rendered images and FLIP maps do not. In the ``runs`` mode the
costs are the input jobs' rows: the same input jobs give the same bytes.
"""

from __future__ import annotations

from typing import (
    TYPE_CHECKING,
    Any,
    NotRequired,  # pydantic needs this TypedDict on 3.11
)

from typing_extensions import TypedDict

from evaluators.report.kind import gather_rows
from evaluators.report.select_params import SelectParams
from evaluators.report.timing import PASS_COSTS
from evaluators.score.params import IMAGE_METRICS
from jobapi.documents import TimingDocument, document, read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Figure, Kind, register
from jobapi.metric_names import qualified
from jobapi.results import ArtifactReader, ResultTable
from jobapi.rows import ResultRow, RowSource, base_row, lower_is_better, number

if TYPE_CHECKING:
    from jobapi.context import JobContext

FORMAT = "matforge.select/1"


@document
class SelectRelative(TypedDict):
    """A cost relative to the reference kernel timed in the same pass: the distribution
    of per-round ratios."""

    median: float
    """The median ratio."""
    min: float
    """The least ratio."""
    max: float
    """The largest ratio."""
    iqr: float
    """Interquartile range of the ratios."""
    n: int
    """Rounds."""


@document
class SelectRung(TypedDict):
    """One rung of a ladder, in order of increasing cost."""

    candidate: str
    """The candidate (a run's label, or the scene mode's rung name)."""
    value: float
    """Its mean ``metric`` over seeds."""
    n: int
    """Seeds (runs) behind the value."""
    min: float
    """The smallest value over seeds."""
    max: float
    """The largest value over seeds."""
    cost: float
    """Its ``cost``."""
    runtime: str | None
    """What evaluated it (``drjit-fused``, ``onnxruntime``, ``mitsuba``; ``null``: unknown)."""
    meets: bool
    """Whether the value meets the target."""
    cost_min: NotRequired[float]
    """Timing pass: the least of its repeats (the cost's spread, low end)."""
    cost_max: NotRequired[float]
    """Timing pass: the largest of its repeats."""
    cost_n: NotRequired[int]
    """Timing pass: its repeats."""
    relative: NotRequired[SelectRelative | None]
    """Timing pass: its cost over the reference kernel's, per round."""
    spp: NotRequired[int]
    """Scene mode: samples per pixel of its render."""
    render_seconds: NotRequired[float]
    """Scene mode: its render's wall seconds (scene load and passes); a timing, so
    ``select.json`` is a timing artifact in the scene mode (varies between runs)."""
    frame_seconds: NotRequired[float]
    """Scene mode: its frame time with compiled kernels (a timing, as ``render_seconds``)."""
    integrator: NotRequired[str]
    """Scene mode: the integrator it rendered with."""
    material: NotRequired[dict[str, Any]]
    """Scene mode: its material, as given."""
    image: NotRequired[str]
    """Scene mode: its image artifact (``rung_<name>.exr``)."""


@document
class SelectLadder(TypedDict):
    """The rungs of one dataset and scene, and the choice."""

    dataset: str | None
    """The dataset the rungs share (``null``: none)."""
    scene: str | None
    """The scene they share (``null``: none)."""
    metric: str
    """The quality metric."""
    cost: str
    """The cost column."""
    cost_label: str | None
    """The cost axis label."""
    rungs: list[SelectRung]
    """The rungs by increasing cost."""
    chosen: str | None
    """The cheapest rung that meets the target (``null``: none does)."""
    why: str
    """The reason, in words."""
    resolved: NotRequired[bool]
    """Whether the choice holds anywhere inside the spreads (seed min..max against the
    target, timing min..max between rungs); ``false``: not resolved, see ``tie``."""
    tie: NotRequired[list[str]]
    """The rungs the choice cannot be told from within the spreads (empty: resolved)."""


@document
class SelectDocument(TypedDict):
    """``select.json`` of ``select``."""

    format: str
    """``matforge.select/1``."""
    metric: str
    """The quality metric (``params.metric``)."""
    target: float
    """The target it must meet (``params.target``)."""
    cost: str
    """What cheapest is measured in (``params.cost``)."""
    lower_is_better: bool
    """Whether meeting the target is ``<=`` (an error) or ``>=``."""
    ladders: list[SelectLadder]
    """One ladder per dataset and scene."""
    runs: NotRequired[list[str]]
    """Runs mode: the ``job:<id>`` refs chosen among."""
    mode: NotRequired[str]
    """Scene mode: ``scene``."""
    scene: NotRequired[dict[str, Any]]
    """Scene mode: the scene, as given."""
    reference: NotRequired[str | dict[str, Any]]
    """Scene mode: the reference, as given (a ref or a material with its spp)."""
    ladder: NotRequired[list[dict[str, Any]]]
    """Scene mode: the ladder, as given."""
    timing: NotRequired[TimingDocument]
    """The job's timing pass (``matforge.timing/1``: machine, settings, per-candidate
    distributions), when the ladder is ranked by ``ns_per_eval``."""


def _rung(p: dict[str, Any], target: float, lower: bool) -> SelectRung:
    rung: SelectRung = {
        "candidate": p["candidate"],
        "value": p["mean"],
        "n": p["n"],
        "min": p["min"],
        "max": p["max"],
        "cost": p["cost"],
        "runtime": p.get("runtime"),
        "meets": p["mean"] <= target if lower else p["mean"] >= target,
    }
    if p.get("cost_min") is not None and p.get("cost_max") is not None:
        rung["cost_min"], rung["cost_max"] = p["cost_min"], p["cost_max"]
        rung["cost_n"] = p["cost_n"]
        rung["relative"] = p.get("relative")
    return rung


def choice_ties(rungs: list[SelectRung], chosen: SelectRung | None, target: float,
                lower: bool) -> list[str]:  # fmt: skip
    """The rungs the choice cannot be told from within the spreads: with a chosen rung,
    the others that may meet the target (their seed range reaches it) and may cost no more
    (their timing range reaches the chosen's), and the chosen itself when its own seed
    range straddles the target; with none chosen, the rungs that may meet it. With one
    seed a value has no range; without a timing pass a cost has none."""

    def range_of(r: SelectRung) -> tuple[float, float]:
        return (r["min"], r["max"]) if r["n"] >= 2 else (r["value"], r["value"])

    def may_meet(r: SelectRung) -> bool:
        lo, hi = range_of(r)
        return lo <= target if lower else hi >= target

    def surely_meets(r: SelectRung) -> bool:
        lo, hi = range_of(r)
        return hi <= target if lower else lo >= target

    if chosen is None:
        return [r["candidate"] for r in rungs if may_meet(r)]
    top = chosen.get("cost_max", chosen["cost"])
    ties = [
        r["candidate"]
        for r in rungs
        if r is not chosen and may_meet(r) and r.get("cost_min", r["cost"]) <= top
    ]
    if ties or not surely_meets(chosen):
        ties.insert(0, chosen["candidate"])
    return ties


def ladders(panels: list[dict[str, Any]], target: float, lower: bool) -> list[SelectLadder]:
    """Per panel, the rungs by increasing cost with ``meets``, the chosen rung, and whether
    the choice is resolved within the spreads (:func:`choice_ties`)."""
    out: list[SelectLadder] = []
    for panel in panels:
        points = sorted(panel["points"], key=lambda p: (p["cost"], p["candidate"]))
        rungs = [_rung(p, target, lower) for p in points]
        chosen = next((r for r in rungs if r["meets"]), None)
        rel = "<=" if lower else ">="
        if chosen is not None:
            why = (
                f"{chosen['candidate']}: {panel['metric']} {chosen['value']:.4g} {rel} "
                f"{target:g} at {panel['cost']} {chosen['cost']:.4g}, the cheapest of "
                f"{sum(r['meets'] for r in rungs)} that meet it"
            )
        else:
            best = min(rungs, key=lambda r: r["value"] if lower else -r["value"])
            why = (
                f"no rung has {panel['metric']} {rel} {target:g}; the best is "
                f"{best['candidate']} at {best['value']:.4g}"
            )
        tie = choice_ties(rungs, chosen, target, lower)
        if panel.get("job_timed"):  # costs each job timed itself: separate passes
            tie = [r["candidate"] for r in rungs]
            why += (
                f"; not resolved: {panel['cost']} is each run's own timing, taken in separate "
                "passes, so the rungs' order by it is not decided (ns_per_eval is re-timed "
                "in one pass)"
            )
        elif tie:
            why += f"; not resolved: {' and '.join(tie)} cannot be told apart within the " + (
                "seed and timing spreads" if chosen is not None else "seed spread"
            )
        out.append(
            {
                "dataset": panel["dataset"],
                "scene": panel["scene"],
                "metric": panel["metric"],
                "cost": panel["cost"],
                "cost_label": panel["cost_label"],
                "rungs": rungs,
                "chosen": chosen["candidate"] if chosen else None,
                "why": why,
                "resolved": not tie,
                "tie": tie,
            }
        )
    return out


def run_select(params: SelectParams, ctx: JobContext) -> None:
    """Gather the rows (or render and score the ladder), build the ladders and write the
    artifacts."""
    from evaluators.report.plots import select_png

    if params.scene_mode:
        from evaluators.report.select_scene import run_scene_select

        doc = run_scene_select(params, ctx)
        doc.update(format=FORMAT, metric=params.metric, target=params.target, cost=params.cost)
        ctx.put_json("select.json", doc)
        ctx.put_bytes("select.png", select_png(doc["ladders"], params.target), "image/png")
        lad = doc["ladders"][0]
        ctx.progress(1.0, f"{len(lad['rungs'])} rungs; chosen: {lad['chosen'] or 'none'}")
        return
    run_runs_select(params, ctx)


def run_runs_select(params: SelectParams, ctx: JobContext) -> None:
    """The first mode: the ladders of rungs other jobs scored."""
    from evaluators.report.fronts import panels
    from evaluators.report.kind import ReportParetoParams, timed_pass
    from evaluators.report.plots import select_png
    from evaluators.report.timing import timing_summary

    assert params.runs is not None
    rows = gather_rows(ReportParetoParams(runs=params.runs), ctx)
    timing = timed_pass(rows, [params.metric], [params.cost], params.timing, ctx)
    found = panels(rows, [params.metric], [params.cost], timing)
    if not found:
        metrics = sorted({r.metric for r in rows})
        raise JobFailed(
            f"no {params.metric} rows with a {params.cost}; the runs measured "
            f"{', '.join(metrics) or 'nothing'}"
        )
    lower = lower_is_better(params.metric) is not False
    result = ladders(found, params.target, lower)
    doc: SelectDocument = {
        "format": FORMAT,
        "runs": list(params.runs),
        "metric": params.metric,
        "target": params.target,
        "lower_is_better": lower,
        "cost": params.cost,
        "ladders": result,
    }
    if timing is not None:
        doc["timing"] = timing_summary(timing)
    ctx.put_json("select.json", doc)
    ctx.put_bytes("select.png", select_png(result, params.target), "image/png")
    picks = "; ".join(f"{lad['chosen'] or 'none'}" for lad in result)
    ctx.progress(1.0, f"{len(result)} ladders; chosen: {picks}")


COLUMNS = ("value", "cost", "runtime", "meets", "chosen")


def summarize(read: ArtifactReader) -> ResultTable | None:
    """One row per ladder and rung (``"<dataset> / <candidate>"`` when several ladders)."""
    doc = read_typed(read("select.json"), SelectDocument)
    if doc is None:
        return None
    several = len(doc["ladders"]) > 1
    rows: dict[str, dict[str, Any]] = {}
    for lad in doc["ladders"]:
        for r in lad["rungs"]:
            label = f"{lad['dataset']} / {r['candidate']}" if several else r["candidate"]
            rows[label] = {
                "value": r["value"],
                "cost": r["cost"],
                "runtime": r["runtime"],
                "meets": r["meets"],
                "chosen": r["candidate"] == lad["chosen"],
            }
    claims: list[dict[str, Any]] = [
        {
            "claim": f"cheapest rung meeting {doc['metric']} target {doc['target']}",
            "holds": None if lad.get("resolved") is False else lad["chosen"] is not None,
            "why": lad["why"],
        }
        for lad in doc["ladders"]
    ]
    return ResultTable(
        title="Cheapest rung meeting the target",
        label_header="Rung",
        columns=list(COLUMNS),
        rows=rows,
        claims=claims,
        settings={"metric": doc["metric"], "target": doc["target"], "cost": doc["cost"]},
        # the rungs are ranked by the target rule (the chosen column), not per column:
        # the cheapest rung is no "best" when it fails the target
        ranked=False,
    )


#: The metric names of the scene mode's rows (:attr:`jobapi.kinds.Kind.metrics`).
SELECT_METRICS = tuple(qualified("image", m) for m in IMAGE_METRICS)


def select_rows(src: RowSource) -> list[ResultRow]:
    """Result rows of the scene mode: per rung, its metric against the reference (named in
    image space, ``image.flip``: :mod:`jobapi.metric_names`) with its
    spp, ``render_seconds`` and model cost. The ``runs`` mode has none of its own (its rows
    are its runs')."""
    doc = read_typed(src.read("select.json"), SelectDocument)
    if doc is None or doc.get("mode") != "scene":
        return []
    metric, cost = qualified("image", doc["metric"]), doc["cost"]
    out = []
    for lad in doc["ladders"]:
        for r in lad["rungs"]:
            value = number(r["value"])
            if value is None:
                continue
            costs: dict[str, Any] = {"render_seconds": number(r.get("render_seconds"))}
            costs["spp"] = r.get("spp")
            # frame_seconds is the scene mode's own measure, not a result-row cost: it
            # goes with the rung's config
            if cost not in ("render_seconds", "spp", "frame_seconds"):
                costs[cost] = number(r["cost"])
            out.append(
                base_row(
                    src,
                    metric,
                    value,
                    dataset=str(lad["dataset"]),
                    scene=lad["scene"],
                    candidate=r["candidate"],
                    runtime=r["runtime"],
                    config={
                        "material": r.get("material"),
                        "integrator": r.get("integrator"),
                        "frame_seconds": number(r.get("frame_seconds")),
                    },
                    **costs,
                )
            )
    return out


def _renders(params: SelectParams) -> bool:
    """Whether the job renders its ladder (scene mode), so that its bytes depend on the
    Mitsuba variant; choosing among finished runs renders nothing."""
    return bool(params.scene_mode)


#: Scene-mode costs that the job times itself.
TIMED_COSTS = ("frame_seconds", "render_seconds")


def _timed(params: SelectParams) -> tuple[str, ...]:
    """The artifacts that hold timings the job measured itself: in the scene mode
    ``select.json`` (every rung's ``render_seconds`` and ``frame_seconds``), and its plot
    when the ladder is ranked, labelled and chosen by one of them (``cost:
    render_seconds`` or ``frame_seconds``; by ``spp`` or a model's cost the plot is the same
    bytes). A ``runs`` choice reads its input jobs' rows: the same input jobs give the same
    bytes."""
    if not params.scene_mode:
        return ("select.json", "select.png") if params.cost in PASS_COSTS else ()
    if params.cost in TIMED_COSTS or params.cost in PASS_COSTS:
        return ("select.json", "select.png")
    return ("select.json",)


register(
    Kind(
        name="select",
        variant_bytes=_renders,
        params=SelectParams,
        runner=run_select,
        description="The cheapest candidate that meets a quality target (e.g. FLIP <= 0.05), "
        "from scored runs, or by rendering a ladder of materials in a scene (shards on the "
        "job's executor) and scoring each against the reference: per reference, the ladder "
        "of rungs by cost, which meet the target, and the one chosen.",
        artifacts=("select.json", "select.png"),
        timing_artifacts=_timed,
        documents={"select.json": SelectDocument},
        smoke={
            "runs": ["step:train.brdf"],
            "metric": "smape",
            "target": 2.0,
            "cost": "ns_per_eval",
            "timing": {"batch": 4096, "min_sample_ms": 0},
        },
        figures=(
            Figure(
                "select.png",
                caption=(
                    "Each reference's ladder of candidates by cost, the target and the one chosen."
                ),
                lead=True,
            ),
        ),
        summary=summarize,
        rows=select_rows,
        metrics=SELECT_METRICS,
    )
)
