"""The ``generate.merl`` job kind: MERL tables of known ground truth.

Turns one material source, or a seeded collection drawn from declared families
(:mod:`generators.merl.collections`), into isotropic BRDF tables in the MERL layout
(Matusik et al. 2003; :mod:`storage.formats.merl`). Tabulation is
:mod:`materials.tabulate`: one value per bin at its centre, ``-1`` below the horizon, with
an anisotropy probe (the format is isotropic).

Artifacts, per material ``<name>``:

- ``<name>.binary``: the table (``(90, 90, phi_d_bins)``, physical values in 1/sr); with
  ``measurement`` set, the simulated measurement (noise, missing grazing bins, dropout);
- ``truth/<name>.binary``: with ``measurement`` only, the noiseless ground truth;
- ``<name>.png``: the half/diff slice view of ``<name>.binary``
(:mod:`evaluators.metrics.brdf_view`);

and ``materials.json``::

    {"materials": [{"name", "family", "source", "params", "tabulation", "measurement",
                    "artifacts"}, ...],
     "phi_d_bins", "preset", "families", "distributions", "allow_anisotropic",
     "anisotropy_tol"}

``source`` is the exact source dict that reproduces the table (``{"mitsuba": {...}}`` or
``{"analytic": {...}}``), ``params`` the drawn parameters (a single source: its own dict),
``family`` the collection family (``"custom"`` for a single source), ``tabulation`` the
tabulation's report (anisotropy and reciprocity errors, variant; no timings, so that the
same spec gives the same bytes).

Parallelism and resumption: one shard per material through ``ctx.map_shards``; a shard
returns the finished file contents, so a job resumed after a crash only tabulates the
materials it had not finished.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, Literal

import numpy as np
from pydantic import AfterValidator, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from evaluators.metrics.brdf_view import halfdiff_slice_png
from evaluators.render.sources.common import load_bsdf, material_sources
from generators.merl.collections import (
    FAMILIES,
    PRESETS,
    SAFE_NAME,
    BlendDistribution,
    FamilyName,
    IridescentDistribution,
    MetalDistribution,
    PaintDistribution,
    PlannedMaterial,
    PlasticDistribution,
    PresetName,
    SheenDistribution,
    draw_collection,
)
from generators.rows import summary_rows
from jobapi.documents import read_typed
from jobapi.errors import JobFailed
from jobapi.kinds import Axis, Figure, Kind, register
from jobapi.params import StrictModel
from jobapi.results import ArtifactReader, ResultTable, flatten, used_columns
from materials.analytic import ANALYTIC_MODELS, build_analytic
from materials.measurement import simulate_measurement
from materials.tabulate import ANISOTROPY_TOL, tabulate_analytic, tabulate_mitsuba
from storage.formats.merl import MerlTable, merl_bytes
from storage.formats.merl_materials import MerlMaterials

if TYPE_CHECKING:
    from jobapi.context import JobContext

#: Most materials one job may tabulate (a table is 35 MB at 180 phi_d bins, 70 MB at 360).
MAX_MATERIALS = 500


def _invalid(message: str) -> PydanticCustomError:
    # A custom error type keeps pydantic from prefixing "Value error, " to the message.
    return PydanticCustomError("generate_merl", message)


def _check_mitsuba(value: dict[str, Any]) -> dict[str, Any]:
    # The render kind's check of {"mitsuba": ...} dicts: a 'type', no 'filename' anywhere.
    try:
        return dict(material_sources()["mitsuba"].adapter.validate_python(value, strict=True))
    except ValidationError as exc:
        raise _invalid(exc.errors()[0]["msg"].removeprefix("Value error, ")) from None


def _check_parameter_types(value: dict[str, Any]) -> None:
    # The models' own checks assume numbers where numbers belong; say which one is not.
    cls = ANALYTIC_MODELS.get(value.get("model"))  # type: ignore[arg-type]
    if cls is None:
        return  # build_analytic names the unknown model
    declared = {f.name: str(f.type) for f in dataclasses.fields(cls) if f.init}
    for key, v in value.items():
        kind = declared.get(key, "")
        is_number = isinstance(v, int | float) and not isinstance(v, bool)
        if kind == "float" and not is_number:
            raise _invalid(f"{key}: must be a number, got {type(v).__name__}")
        if "RGB" in kind and v is not None and not is_number:
            ok = isinstance(v, list) and len(v) == 3
            if not ok or not all(isinstance(c, int | float) and not isinstance(c, bool) for c in v):
                raise _invalid(f"{key}: must be [r, g, b] numbers, got {v!r}")
        if kind == "bool" and not isinstance(v, bool):
            raise _invalid(f"{key}: must be true or false, got {type(v).__name__}")


def _check_analytic(value: dict[str, Any]) -> dict[str, Any]:
    _check_parameter_types(value)
    try:
        build_analytic(value)
    except (ValueError, TypeError) as exc:
        raise _invalid(str(exc)) from None
    return value


class MerlSource(StrictModel):
    """One material source: exactly one of ``mitsuba`` or ``analytic``."""

    mitsuba: Annotated[dict[str, Any], AfterValidator(_check_mitsuba)] | None = Field(
        default=None,
        description='A Mitsuba 3 BSDF plugin dict, e.g. {"type": "roughconductor", '
        '"alpha": 0.2, "material": "Au"}; no \'filename\' keys. Evaluated in the Mitsuba '
        "variant that MATFORGE_VARIANT sets.",
    )
    analytic: Annotated[dict[str, Any], AfterValidator(_check_analytic)] | None = Field(
        default=None,
        description='An analytic model {"model": name, **parameters}, e.g. {"model": "ggx", '
        '"alpha": 0.3, "material": "Au"}; models: lambert, ggx, beckmann, plastic, '
        "thin_film_ggx (materials.analytic).",
    )

    @model_validator(mode="after")
    def _exactly_one(self) -> MerlSource:
        if (self.mitsuba is None) == (self.analytic is None):
            raise _invalid("give exactly one of 'mitsuba' or 'analytic'")
        return self

    def as_dict(self) -> dict[str, Any]:
        """``{"mitsuba": {...}}`` or ``{"analytic": {...}}``."""
        if self.mitsuba is not None:
            return {"mitsuba": copy.deepcopy(self.mitsuba)}
        return {"analytic": copy.deepcopy(self.analytic)}


class Distributions(StrictModel):
    """Per-family overrides of the default distributions (merl_collections)."""

    metal: MetalDistribution | None = Field(default=None, description="Metal distribution.")
    plastic: PlasticDistribution | None = Field(default=None, description="Plastic distribution.")
    paint: PaintDistribution | None = Field(default=None, description="Paint distribution.")
    sheen: SheenDistribution | None = Field(default=None, description="Sheen distribution.")
    blend: BlendDistribution | None = Field(default=None, description="Blend distribution.")
    iridescent: IridescentDistribution | None = Field(
        default=None, description="Iridescent film distribution."
    )


class CollectionParams(StrictModel):
    """A seeded collection: a named ``preset`` or explicit ``families`` counts."""

    preset: PresetName | None = Field(
        default=None,
        description="Named collection: 'small' (12 materials, every family) or 'merl100' "
        "(100 materials, the MERL database's spread).",
    )
    families: dict[FamilyName, Annotated[int, Field(ge=0, le=MAX_MATERIALS)]] | None = Field(
        default=None,
        description='Materials per family, e.g. {"metal": 4, "paint": 2}; families: '
        + ", ".join(FAMILIES)
        + ".",
    )
    distributions: Distributions | None = Field(
        default=None,
        description="Overrides of the families' parameter distributions; a family's "
        "unspecified fields keep their defaults.",
    )

    @model_validator(mode="after")
    def _check(self) -> CollectionParams:
        if (self.preset is None) == (self.families is None):
            raise _invalid("give exactly one of 'preset' or 'families'")
        counts = self.counts()
        if not 1 <= sum(counts.values()) <= MAX_MATERIALS:
            raise _invalid(
                f"a collection needs 1..{MAX_MATERIALS} materials, got {sum(counts.values())}"
            )
        for family in FAMILIES:
            if getattr(self.distributions, family, None) is not None and not counts.get(family):
                raise _invalid(f"distributions.{family}: the collection has no {family} materials")
        return self

    def counts(self) -> dict[str, int]:
        """Materials per family."""
        if self.preset is not None:
            return dict(PRESETS[self.preset].counts)
        return {str(family): n for family, n in (self.families or {}).items()}

    def summary(self) -> dict[str, Any]:
        """``preset``, ``families`` (counts) and the ``distributions`` drawn from."""
        counts = self.counts()
        dists = {f: self.distribution(f).model_dump(mode="json") for f, n in counts.items() if n}
        return {"preset": self.preset, "families": counts, "distributions": dists}

    def distribution(self, family: str) -> StrictModel:
        """The distribution ``family`` is drawn from: the override, else the default."""
        override = getattr(self.distributions, family, None)
        return override if override is not None else FAMILIES[family].distribution()


class MeasurementParams(StrictModel):
    """Simulated gonioreflectometer imperfections (materials.measurement)."""

    noise_sigma: float = Field(
        default=0.05,
        ge=0.0,
        le=1.0,
        description="Multiplicative lognormal noise: value * exp(sigma z - sigma^2/2), "
        "z ~ N(0, 1), independent per bin and channel.",
    )
    grazing_deg: float = Field(
        default=80.0,
        gt=0.0,
        le=90.0,
        description="Bins whose theta_i or theta_o exceeds this (degrees) are missing (-1).",
    )
    dropout: float = Field(
        default=0.0, ge=0.0, lt=1.0, description="Probability of losing any other bin."
    )


class MerlParams(StrictModel):
    """Parameters of ``generate.merl``.

    =====================  ======================  =======  ================================
    name                   type                    default  meaning
    =====================  ======================  =======  ================================
    ``source``             ``{mitsuba|analytic}``  none     one material (or ``collection``)
    ``collection``         preset or families      none     many materials (or ``source``)
    ``name``               string                  derived  file name of a single source
    ``phi_d_bins``         180 or 360              180      phi_d resolution of the tables
    ``measurement``        noise and masks         none     simulate a measurement
    ``allow_anisotropic``  bool                    false    tabulate anisotropic sources
    =====================  ======================  =======  ================================

    Example::

        {"kind": "generate.merl", "seed": 3, "params": {"collection": {"preset": "small"},
         "measurement": {"noise_sigma": 0.02, "grazing_deg": 80}}}
    """

    source: MerlSource | None = Field(
        default=None,
        description='One material: {"mitsuba": {<BSDF plugin dict>}} or {"analytic": '
        '{"model": ..., ...}}. Give exactly one of source or collection.',
    )
    collection: CollectionParams | None = Field(
        default=None,
        description='Many materials drawn (seeded) from families: {"preset": "small" | '
        '"merl100"} or {"families": {family: count}}, optional "distributions".',
    )
    name: str | None = Field(
        default=None,
        pattern=SAFE_NAME.pattern,
        description="File name (no extension) of a single source's table; default: the "
        "Mitsuba plugin type or the analytic model name. Letters, digits, '-' and '_'.",
    )
    phi_d_bins: Literal[180, 360] = Field(
        default=180,
        description="phi_d bins: 180 (the MERL layout, folded by reciprocity) or 360.",
    )
    measurement: MeasurementParams | None = Field(
        default=None,
        description="Simulate a measurement: <name>.binary gets noise and missing bins, and "
        "truth/<name>.binary keeps the ground truth. Default: none.",
    )
    allow_anisotropic: bool = Field(
        default=False,
        description="Tabulate sources that change when rotated about the normal (the format "
        "is isotropic) and record the error; by default such a source fails the job.",
    )

    @model_validator(mode="after")
    def _check(self) -> MerlParams:
        if (self.source is None) == (self.collection is None):
            raise _invalid("give exactly one of 'source' or 'collection'")
        if self.name is not None and self.collection is not None:
            raise _invalid("'name' applies to a single source; collections name materials")
        return self


def default_name(source: dict[str, Any]) -> str:
    """A single source's default material name: its plugin type or model, made safe."""
    ((key, inner),) = source.items()
    raw = str(inner.get("type" if key == "mitsuba" else "model", "material"))
    name = "".join(c if c.isalnum() or c in "-_" else "_" for c in raw)
    return name if SAFE_NAME.fullmatch(name) else "material"


def plan_materials(params: MerlParams, ctx: JobContext) -> list[PlannedMaterial]:
    """The materials of a job, in artifact order, with unique file-system-safe names."""
    if params.source is not None:
        source = params.source.as_dict()
        ((_, inner),) = source.items()
        name = params.name or default_name(source)
        return [PlannedMaterial(name, "custom", source, copy.deepcopy(inner))]
    coll = params.collection
    assert coll is not None
    dists = {family: coll.distribution(family) for family in coll.counts()}
    return draw_collection(coll.counts(), dists, lambda f: ctx.rng(f"generate.merl/{f}"))


@dataclass(frozen=True)
class MaterialTask:
    """One shard: everything needed to tabulate one material (picklable)."""

    name: str
    source: dict[str, Any]
    phi_d_bins: int
    allow_anisotropic: bool
    measurement: dict[str, float] | None
    measurement_seed: int | None


def tabulate_material(task: MaterialTask) -> dict[str, Any]:
    """Shard function: tabulate one material; returns file contents and the report.

    Returns ``{"binary": bytes, "truth": bytes | None, "missing_bins": int, "png": bytes,
    "info": dict, "seconds": float}`` (``truth`` only with a measurement). Raises
    :class:`JobFailed` naming the material when the source does not build, is anisotropic
    (unless allowed) or gives non-finite values.
    """
    started = time.perf_counter()
    ((key, inner),) = task.source.items()
    try:
        if key == "mitsuba":
            from materials.backend import load_mitsuba

            mi = load_mitsuba()
            bsdf = load_bsdf(inner, mi, f"material {task.name!r}")
            table, info = tabulate_mitsuba(bsdf, phi_d_bins=task.phi_d_bins, allow_anisotropic=True)
        else:
            table, info = tabulate_analytic(
                build_analytic(inner), phi_d_bins=task.phi_d_bins, allow_anisotropic=True
            )
    except (ValueError, TypeError, RuntimeError) as exc:
        raise JobFailed(f"material {task.name!r}: {exc}") from None
    info.pop("eval_seconds", None)  # a timing: it would break byte-identical artifacts
    aniso = float(info["anisotropy_error"])
    if aniso > ANISOTROPY_TOL and not task.allow_anisotropic:
        raise JobFailed(
            f"material {task.name!r} is anisotropic: its BRDF changes by {aniso:.3g} "
            f"(relative) when rotated about the normal, above the tolerance "
            f"{ANISOTROPY_TOL:g}; MERL tables are isotropic. Use an isotropic source, or set "
            f"allow_anisotropic: true to tabulate it and record the error"
        )
    bad = int(np.count_nonzero(~np.isfinite(table.rgb)))
    if bad:
        raise JobFailed(f"material {task.name!r}: the source gave {bad} non-finite values")
    delivered: MerlTable = table
    truth: bytes | None = None
    if task.measurement is not None:
        rng = np.random.default_rng(task.measurement_seed)
        delivered = simulate_measurement(table, rng, **task.measurement)
        truth = merl_bytes(table)
    return {
        "binary": merl_bytes(delivered),
        "truth": truth,
        "missing_bins": int(np.count_nonzero(delivered.missing)),
        "png": halfdiff_slice_png(delivered),
        "info": info,
        "seconds": time.perf_counter() - started,
    }


def _measurement_seed(ctx: JobContext, name: str) -> int:
    return int(ctx.rng(f"generate.merl/measurement/{name}").integers(2**63))


def run_generate_merl(params: MerlParams, ctx: JobContext) -> None:
    """Tabulate every material and store its table, picture and ``materials.json``."""
    ctx.progress(0.0, "planning materials")
    planned = plan_materials(params, ctx)
    measurement = params.measurement.model_dump() if params.measurement is not None else None
    tasks = [
        MaterialTask(
            name=m.name,
            source=m.source,
            phi_d_bins=params.phi_d_bins,
            allow_anisotropic=params.allow_anisotropic,
            measurement=measurement,
            measurement_seed=_measurement_seed(ctx, m.name) if measurement is not None else None,
        )
        for m in planned
    ]
    started = time.perf_counter()
    results = ctx.map_shards(
        tabulate_material,
        tasks,
        keys=[f"material-{m.name}" for m in planned],
        label="material",
        progress_range=(0.02, 0.95),
    )
    records = []
    for m, task, res in zip(planned, tasks, results, strict=True):
        ctx.check_cancelled()
        artifacts = {"table": f"{m.name}.binary", "picture": f"{m.name}.png"}
        ctx.put_bytes(artifacts["table"], res["binary"])
        ctx.put_bytes(artifacts["picture"], res["png"], "image/png")
        if res["truth"] is not None:
            artifacts["truth"] = f"truth/{m.name}.binary"
            ctx.put_bytes(artifacts["truth"], res["truth"])
        measured = None
        if measurement is not None:
            measured = {
                **measurement,
                "seed": task.measurement_seed,
                "missing_bins": res["missing_bins"],
            }
        records.append(
            {
                "name": m.name,
                "family": m.family,
                "source": m.source,
                "params": m.params,
                "tabulation": res["info"],
                "measurement": measured,
                "artifacts": artifacts,
            }
        )
    coll = params.collection.summary() if params.collection is not None else None
    ctx.put_json(
        "materials.json",
        {
            "materials": records,
            "phi_d_bins": params.phi_d_bins,
            **(coll or {"preset": None, "families": None, "distributions": None}),
            "allow_anisotropic": params.allow_anisotropic,
            "anisotropy_tol": ANISOTROPY_TOL,
        },
    )
    seconds = time.perf_counter() - started
    per = sum(r["seconds"] for r in results) / max(1, len(results))
    ctx.progress(
        1.0,
        f"{len(planned)} MERL table(s) in {seconds:.1f} s ({per:.2f} s per table in its shard)",
    )


def summarize(read: ArtifactReader) -> ResultTable | None:
    """The result table: ``materials.json``, one row per material (family, source, the
    tabulation's and the measurement's figures)."""
    doc = read_typed(read("materials.json"), MerlMaterials)
    if doc is None:
        return None
    rows: dict[str, dict[str, Any]] = {}
    for m in doc["materials"]:
        row: dict[str, Any] = {"family": m["family"], "source": next(iter(m["source"]), None)}
        for key, value in flatten({"tabulation": m["tabulation"]}).items():
            if isinstance(value, int | float | str | bool):
                row[key] = value
        if m["measurement"] is not None:
            row["missing_bins"] = m["measurement"].get("missing_bins")
        rows[m["name"]] = row
    if not rows:
        return None
    columns: list[str] = []
    for row in rows.values():
        columns.extend(k for k in row if k not in columns)
    return ResultTable(
        title="Materials",
        label_header="Material",
        columns=used_columns(columns, rows),
        rows=rows,
        ranked=False,  # a collection's table quality: measured, no material is "the best"
    )


def _tabulated_by_mitsuba(params: MerlParams) -> bool:
    """Whether the tables come from Dr.Jit kernels (a Mitsuba source, or a collection,
    whose families are Mitsuba BSDFs), so that their bytes depend on the variant; an
    analytic source is numpy."""
    return params.source is None or params.source.mitsuba is not None


register(
    Kind(
        name="generate.merl",
        variant_bytes=_tabulated_by_mitsuba,
        params=MerlParams,
        runner=run_generate_merl,
        description="MERL-format isotropic BRDF tables of known ground truth from Mitsuba 3 "
        "BSDFs, analytic models or seeded collections of material families.",
        artifacts=("*.binary", "*.png", "materials.json"),
        documents={"materials.json": MerlMaterials},
        smoke={"source": {"analytic": {"model": "ggx", "alpha": 0.3, "material": "Au"}}},
        summary=summarize,
        rows=summary_rows(summarize, ("missing_bins",), prefix="tabulation."),
        metrics=("missing_bins", "tabulation.*"),
        figures=(
            Figure(
                "*.png",
                caption="Half/difference slice at φd = 90° (Burley 2012), Reinhard tone map.",
                x=Axis("θh (square-root spacing)", "0°", "90°"),
                y=Axis("θd", "0°", "90°"),
            ),
        ),
    )
)
