"""The params of the ``select`` kind (:mod:`evaluators.report.select` documents the kind):
either ``runs`` (rungs already scored) or ``scene``, ``reference`` and ``ladder`` (rendered
and scored by the job, :mod:`evaluators.report.select_scene`)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    StringConstraints,
    ValidationError,
    model_serializer,
    model_validator,
)

from evaluators.render.kind import RenderParams
from evaluators.render.sources import MaterialParam
from evaluators.report.kind import CostName, drop_default_timing
from evaluators.report.timing import TimingParams
from evaluators.score.params import IMAGE_METRICS
from jobapi.params import JobRef, Ref, StrictModel

RungName = Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]
#: Costs a scene-mode ladder may be chosen by: measured here (the first three), or its
#: model job's (the rest). ``frame_seconds`` is the scene mode's own (see
#: :mod:`evaluators.report.select_scene`); the others are result-row costs.
SCENE_COSTS = (
    "frame_seconds",
    "render_seconds",
    "spp",
    "ns_per_eval",
    "bytes_per_material",
    "bytes_per_network",
    "macs_per_eval",
    "bytes_per_eval",
)
#: The costs measured in the shard, not read from a model job.
MEASURED_COSTS = SCENE_COSTS[:3]


class ReferenceRender(StrictModel):
    """A reference path-traced in the ladder's scene: ``{material, spp}``."""

    material: MaterialParam = Field(description="The reference material, as in 'render'.")
    spp: int = Field(default=256, ge=1, le=65536, description="Samples per pixel, 1..65536.")


class Rung(StrictModel):
    """One candidate of a scene-mode ladder: ``{name, material, spp?}``."""

    name: RungName = Field(description="The rung's label: 1-64 of A-Z a-z 0-9 _ . -")
    material: MaterialParam = Field(description="The material, as in 'render'.")
    spp: int | None = Field(
        default=None, ge=1, le=65536, description="Samples per pixel (default: the scene's)."
    )


def _null(*keys: str) -> dict[str, Any]:
    return {k: {"type": "null"} for k in keys}


def _given(*keys: str) -> dict[str, Any]:
    return {k: {"not": {"type": "null"}} for k in keys}


#: The two modes in the JSON schema (``oneOf``), so that a spec the schema allows is not
#: refused for its mode: ``runs`` with none of the scene mode's fields (each absent or
#: null), and not ``cost: frame_seconds``; or ``scene``, ``reference`` and ``ladder``
#: without ``runs``, with an image metric, a cost measured there or a model's, no
#: ``scene.material`` and no rung called ``reference``. What a schema cannot state stays a
#: 422 naming the field: rung names listed twice, a model's cost for a rung that is no
#: model, a rung's render over the path budget.
_MODES: dict[str, Any] = {
    "oneOf": [
        {
            "title": "runs",
            "required": ["runs"],
            "properties": {
                **_given("runs"),
                **_null("scene", "reference", "ladder"),
                "cost": {"not": {"const": "frame_seconds"}},
            },
        },
        {
            "title": "scene",
            "required": ["scene", "reference", "ladder"],
            "properties": {
                **_null("runs"),
                **_given("scene", "reference", "ladder"),
                "scene": {"not": {"anyOf": [{"type": "null"}, {"required": ["material"]}]}},
                "ladder": {
                    "type": "array",
                    "items": {"properties": {"name": {"not": {"const": "reference"}}}},
                },
                "metric": {"enum": list(IMAGE_METRICS)},
                "cost": {"enum": list(SCENE_COSTS)},
            },
        },
    ]
}


class SelectParams(StrictModel):
    """Parameters of ``select``: either ``runs`` (rungs already scored), or ``scene``,
    ``reference`` and ``ladder`` (the job renders and scores them).

    =============  ====================  ==================  ================================
    name           type                  default             meaning
    =============  ====================  ==================  ================================
    ``runs``       list of ``job:<id>``  (mode 1)            jobs with result rows: the ladder
    ``scene``      render params         (mode 2)            a ``render`` spec's params
                                                             without ``material``: scene,
                                                             resolution, spp (the rungs'
                                                             default), max_depth, lights,
                                                             camera
    ``reference``  ref or                (mode 2)            the reference image
                   ``{material, spp}``                       (``job:<id>/image.exr``,
                                                             ``step:<name>``), or a material
                                                             path-traced here (spp 256)
    ``ladder``     list of               (mode 2)            the candidates, 1..32, names
                   ``{name, material,                        unique; material as in
                   spp?}``                                   ``render``
    ``metric``     str                   ``flip``            the quality metric (scene mode:
                                                             flip, psnr, ssim, mae, mse)
    ``target``     float                 required            the value a rung must reach
    ``cost``       cost name             ``render_seconds``  what "cheapest" is measured in
                                                             (scene mode: render_seconds,
                                                             spp, or a ``{"model":
                                                             "job:..."}`` rung's
                                                             ns_per_eval, bytes_per_material,
                                                             bytes_per_network,
                                                             macs_per_eval,
                                                             bytes_per_eval)
    ``timing``     timing settings       repeats 5 ...       the runs mode's timing pass
                                                             by ns_per_eval (repeats >= 5,
                                                             warmup, batch, threads)
    =============  ====================  ==================  ================================

    Example: ``{"kind": "select", "params": {"runs": ["step:seen_scores"], "metric":
    "flip", "target": 0.05}}``. Scene mode::

        {"kind": "select", "params": {
         "scene": {"scene": "sphere_env", "resolution": [64, 64], "spp": 16},
         "reference": {"material": {"mitsuba": {"type": "roughconductor", "alpha": 0.2}},
                       "spp": 256},
         "ladder": [{"name": "diffuse", "material": {"mitsuba": {"type": "diffuse"}}},
                    {"name": "conductor", "material": {"mitsuba": {"type":
                     "roughconductor", "alpha": 0.2}}}],
         "metric": "flip", "target": 0.1}}
    """

    model_config = ConfigDict(json_schema_extra=_MODES)

    runs: list[JobRef] | None = Field(
        default=None,
        min_length=1,
        max_length=256,
        description="Jobs with result rows: 'job:<id>' each (the first mode).",
    )
    scene: RenderParams | None = Field(
        default=None,
        description="The scene mode: a render spec's params without 'material' (scene, "
        "resolution, spp of the rungs, max_depth, lights, camera).",
    )
    reference: Ref | ReferenceRender | None = Field(
        default=None,
        description="The scene mode's reference: an image ref (job:<id>/image.exr) or "
        "{material, spp} to path-trace it here.",
    )
    ladder: list[Rung] | None = Field(
        default=None,
        min_length=1,
        max_length=32,
        description="The scene mode's candidates: [{name, material, spp?}], names unique.",
    )
    metric: str = Field(
        default="flip", min_length=1, max_length=64, description="The quality metric of the target."
    )
    target: float = Field(
        allow_inf_nan=False,
        description="The value a rung must reach "
        "(at most, for an error; at least, where higher is better).",
    )
    cost: CostName | Literal["frame_seconds"] = Field(
        default="render_seconds",
        description="What cheapest is measured in: a result-row cost, or in the scene mode "
        "frame_seconds (the rung's frame time with its kernels compiled).",
    )

    timing: TimingParams = Field(
        default_factory=TimingParams,
        description="The runs mode's timing pass when cost is ns_per_eval (every rung's "
        "model and the reference kernel, interleaved): repeats (>= 5), warmup, batch, threads.",
    )

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        # The other mode's fields are left out (a runs spec keeps the canonical form, and
        # so the hash, it had before the scene mode), and so is the scene's default
        # material (each rung has its own).
        data: dict[str, Any] = drop_default_timing(handler(self))
        for key in ("runs", "scene", "reference", "ladder"):
            if key in data and data[key] is None:
                del data[key]
        if isinstance(data.get("scene"), dict):
            data["scene"].pop("material", None)
        return data

    @property
    def scene_mode(self) -> bool:
        return self.runs is None

    @model_validator(mode="after")
    def _check_mode(self) -> SelectParams:
        given = [k for k in ("scene", "reference", "ladder") if getattr(self, k) is not None]
        if self.runs is not None:
            if given:
                raise ValueError(
                    f"runs: give either runs (rungs already scored) or scene, reference and "
                    f"ladder (rendered here), not both; also given: {', '.join(given)}"
                )
            if self.cost == "frame_seconds":
                raise ValueError(
                    "cost: frame_seconds is measured by the scene mode's renders; runs carry "
                    "render_seconds"
                )
            return self
        missing = [k for k in ("scene", "reference", "ladder") if k not in given]
        if missing:
            raise ValueError(
                f"{missing[0]}: required: give runs (rungs already scored) or scene, "
                f"reference and ladder (rendered here); missing: {', '.join(missing)}"
            )
        self._check_scene()
        return self

    def _check_scene(self) -> None:
        assert self.scene is not None and self.ladder is not None
        if self.metric.removeprefix("image.") not in IMAGE_METRICS:  # image.flip: flip
            raise ValueError(
                f"metric: {self.metric!r} is not an image metric; one of {', '.join(IMAGE_METRICS)}"
                " (or its row name, image.<metric>)"
            )
        if "material" in self.scene.model_fields_set:
            raise ValueError("scene.material: give each rung's material in ladder instead")
        names = [r.name for r in self.ladder]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"ladder: rung names listed more than once: {', '.join(dupes)}")
        if "reference" in names:
            raise ValueError("ladder: 'reference' is the reference's name; rename the rung")
        if self.cost not in SCENE_COSTS:
            raise ValueError(f"cost: {self.cost} is not measured here; one of {SCENE_COSTS}")
        base = self.scene.model_dump(mode="json", exclude={"material"})
        for i, rung in enumerate(self.ladder):
            if self.cost not in MEASURED_COSTS and not (
                "model" in rung.material or "external" in rung.material
            ):
                raise ValueError(
                    f"ladder.{i}.material: cost {self.cost} is a model's cost (read from its "
                    f'job, or measured for an {{"external": ...}} model); this rung is not a '
                    f'{{"model": "job:<id>/..."}} or {{"external": {{...}}}} material'
                )
            if self.cost == "bytes_per_material" and "external" in rung.material:
                raise ValueError(
                    f"ladder.{i}.material: an external model's parameters are counted as "
                    "bytes_per_network (its param_bytes); choose by that or ns_per_eval"
                )
            spp = rung.spp if rung.spp is not None else self.scene.spp
            _check_render(f"ladder.{i}", {**base, "material": rung.material, "spp": spp})
        if isinstance(self.reference, ReferenceRender):
            ref = {**base, "material": self.reference.material, "spp": self.reference.spp}
            _check_render("reference", ref)


def _check_render(where: str, spec: dict[str, Any]) -> None:
    """``spec`` as the ``render`` kind validates it (the path budget), errors at ``where``."""
    try:
        RenderParams.model_validate(spec)
    except ValidationError as exc:
        msg = exc.errors()[0]["msg"].removeprefix("Value error, ")
        raise ValueError(f"{where}: {msg}") from None
