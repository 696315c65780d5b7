"""Parameters of the ``generate.fabric`` job kind: the spec model, its presets, and the plan.

:class:`FabricGenParams` is the strict params model (validated before a job is queued);
:data:`PRESETS` holds the named defaults (``small``, and ``paper``: Chen et al. 2024,
Sec. 5.1); :meth:`FabricGenParams.resolved` merges explicit fields over the preset into a
:class:`Resolved` configuration, and :func:`plan_sets` lists its materials in artifact
order. The runner and the kind's registration are in :mod:`generators.fabric.kind`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from evaluators.render.scenes import SCENES, Camera, PointLight
from generators.fabric.queries import BTDF_FRACTION, LOG_SIZE_MIN
from generators.fabric.scene_queries import SceneDesign, pixel_footprints
from jobapi.params import StrictModel
from jobapi.presets import resolve_preset
from materials.fabric.patterns import PATTERNS, TRAINING_PATTERNS, UNSEEN_PATTERNS
from materials.fabric.samplers import check_sampling
from storage.formats.fabric_documents import FABRIC_SPLITS

PresetName = Literal["small", "paper", "beta", "unseen_small", "unseen", "unseen_paper"]
#: The ``beta`` preset's range of the height scaling (Sec. 5.1's beta U(0.1, 1.0)).
BETA_SWEEP = (0.1, 1.0)
#: Replicates of the estimator (Sobol's standard error; ``aggregate.py``).
REPLICATES = 4
#: Most materials and queries per material one job may hold.
MAX_MATERIALS = 1000
MAX_QUERIES = 1 << 23


@dataclass(frozen=True)
class FabricPreset:
    """A named configuration; sets are ``{pattern: count}`` with a default for the rest."""

    patterns: tuple[str, ...]
    texture_sets: dict[str, int]
    shading_sets: dict[str, int]
    queries_per_material: int
    samples: int
    shard_queries: int
    map_resolution: int
    beta_sweep: bool = False
    splits: bool = False
    """Whether each material gets a ``split`` (:func:`material_split`) in ``materials.json``."""


#: Splits of a dataset with held-out sets (``unseen*`` presets), in report order.
SPLITS = FABRIC_SPLITS


def material_split(pattern: str, shading_set: int, shading_sets: int) -> str:
    """A material's split in the ``unseen*`` presets.

    ``unseen_pattern``: its pattern is not one of the paper's training patterns (the twill
    4x4 of Fig. 5, :data:`materials.fabric.patterns.UNSEEN_PATTERNS`, or any other pattern
    outside :data:`~materials.fabric.patterns.TRAINING_PATTERNS`). ``unseen_material``: a
    training pattern's last shading set of every texture set (when it has two or more): a
    draw of alpha, beta, w and the albedos that no trained material has (its yarn geometry
    is that of the texture set's other materials). Everything else is ``train``.
    """
    if pattern not in TRAINING_PATTERNS:
        return "unseen_pattern"
    if shading_sets >= 2 and shading_set == shading_sets - 1:
        return "unseen_material"
    return "train"


#: Named presets. ``paper``: Sec. 5.1 (81 + 192 + 192 materials, 160 x 20480 = 3.28 M
#: queries per material, 2048 samples); ``small``: one material per weave family.
PRESETS: dict[str, FabricPreset] = {
    "small": FabricPreset(
        patterns=("plain", "twill_3x3", "satin_5x5"),
        texture_sets={"*": 1},
        shading_sets={"*": 1},
        queries_per_material=1280,
        samples=256,
        shard_queries=640,
        map_resolution=64,
    ),
    "paper": FabricPreset(
        patterns=TRAINING_PATTERNS,
        texture_sets={"plain": 9, "*": 4},
        shading_sets={"plain": 9, "*": 16},
        queries_per_material=3_276_800,
        samples=2048,
        shard_queries=65_536,
        map_resolution=256,
    ),
    # A data set that can teach beta: per pattern, 16 materials that differ only in beta
    # (both yarns, evenly spaced over BETA_SWEEP, ends included); geometry, alpha, w and
    # the albedos are one draw per texture set, as Eq. 7 leaves w and the albedos out. The
    # materials of a texture set share one query set (generators.fabric.kind.plan_materials).
    "beta": FabricPreset(
        patterns=("plain", "twill_3x3", "satin_5x5"),
        texture_sets={"*": 1},
        shading_sets={"*": 16},
        queries_per_material=1280,
        samples=256,
        shard_queries=640,
        map_resolution=64,
        beta_sweep=True,
    ),
    # The paper's shape with held-out sets (materials.json's ``split``): the seven training
    # patterns plus the unseen twill 4x4; every material its own draw of alpha, beta, w and
    # albedos (beta varies within a pattern), the last shading set of every texture set held
    # out as an unseen material. ``unseen_small`` runs in seconds (tests); ``unseen`` is
    # 7 x 4 x 4 + 2 x 2 = 116 materials x 20,480 queries x 256 samples for this machine;
    # ``unseen_paper`` Sec. 5.1's 465 materials (+ 16 twill 4x4) at 2,048 samples for a
    # cluster. Sizes: the paper's strata, as every preset (the spec's ``sizes`` default);
    # scripts/fabric_unseen.yaml asks for log-uniform sizes (renders' footprints).
    "unseen_small": FabricPreset(
        patterns=("plain", "twill_3x3", "satin_5x5", *UNSEEN_PATTERNS),
        texture_sets={"*": 1},
        shading_sets={"*": 2},
        queries_per_material=256,
        samples=64,
        shard_queries=256,
        map_resolution=16,
        splits=True,
    ),
    "unseen": FabricPreset(
        patterns=(*TRAINING_PATTERNS, *UNSEEN_PATTERNS),
        texture_sets={"twill_4x4": 2, "*": 4},
        shading_sets={"twill_4x4": 2, "*": 4},
        queries_per_material=20_480,
        samples=256,
        shard_queries=5_120,
        map_resolution=64,
        splits=True,
    ),
    "unseen_paper": FabricPreset(
        patterns=(*TRAINING_PATTERNS, *UNSEEN_PATTERNS),
        texture_sets={"plain": 9, "*": 4},
        shading_sets={"plain": 9, "twill_4x4": 4, "*": 16},
        queries_per_material=3_276_800,
        samples=2048,
        shard_queries=65_536,
        map_resolution=256,
        splits=True,
    ),
}


def _invalid(message: str) -> PydanticCustomError:
    return PydanticCustomError("generate_fabric", message)


#: Scenes whose material is the flat y = 0 floor square (scene-driven queries need one).
FLOOR_SCENES: tuple[str, ...] = tuple(k for k, v in SCENES.items() if v.floor_half_size)
#: Largest image side of a scene design (the pixel table is built at validation).
MAX_SCENE_SIDE = 1024
SceneSide = Annotated[int, Field(ge=8, le=MAX_SCENE_SIDE)]


class FabricScene(StrictModel):
    """The render a dataset is drawn for (``scene`` of ``generate.fabric``): sizes from its
    pixel footprints, views from its camera, lights from its emitters
    (:mod:`generators.fabric.scene_queries`). Match the ``render`` job's params."""

    name: str = Field(
        description="Built-in scene whose material is the flat floor square: "
        + ", ".join(FLOOR_SCENES)
        + " (the render's 'scene').",
    )
    resolution: Annotated[tuple[SceneSide, SceneSide], Field(strict=False)] = Field(
        default=(256, 256),
        description=f"Image size [width, height] of the render, each 8..{MAX_SCENE_SIDE}.",
    )
    tiles_per_uv: float = Field(
        default=16.0,
        gt=0.0,
        le=4096.0,
        allow_inf_nan=False,
        description="Pattern tiles across the uv range, as the render's fabric material "
        "(its 'tiles_per_uv', default 16).",
    )
    camera: Camera | None = Field(
        default=None, description="The render's camera override. Default: the scene's own."
    )
    lights: list[PointLight] | None = Field(
        default=None,
        max_length=16,
        description="The render's point lights override. Default: the scene's own.",
    )

    @field_validator("name")
    @classmethod
    def _floor_scene(cls, value: str) -> str:
        if value not in FLOOR_SCENES:
            kind = "not a floor scene" if value in SCENES else "unknown scene"
            raise _invalid(
                f"{kind} {value!r}; scene-driven queries need a scene whose material is "
                f"the flat floor square: {', '.join(FLOOR_SCENES)}"
            )
        return value

    @model_validator(mode="after")
    def _check_views(self) -> FabricScene:
        design = self.design()
        if design.camera[0][1] <= 0.0:
            raise _invalid("camera: the origin must be above the floor (y > 0)")
        if not design.lights and design.environment_scale <= 0.0:
            raise _invalid("lights: the scene has no emitter left to draw light directions from")
        # A coarse film over the same view first (fast at 1024 x 1024); only a view that
        # misses there is checked pixel by pixel.
        w, h = design.resolution
        k = max(1, max(w, h) // 128)
        coarse = replace(design, resolution=(max(1, w // k), max(1, h // k)))
        if len(pixel_footprints(coarse)) == 0 and len(pixel_footprints(design)) == 0:
            raise _invalid("camera: no pixel centre's ray hits the floor square")
        return self

    def design(self) -> SceneDesign:
        """The resolved, hashable scene (defaults of :data:`SCENES` filled in)."""
        scene = SCENES[self.name]
        cam = self.camera or scene.camera
        lights = scene.lights if self.lights is None else tuple(self.lights)
        assert scene.floor_half_size is not None
        return SceneDesign(
            name=self.name,
            resolution=(int(self.resolution[0]), int(self.resolution[1])),
            tiles_per_uv=float(self.tiles_per_uv),
            camera=(cam.origin, cam.target, cam.up, float(cam.fov)),
            lights=tuple((light.position, light.intensity) for light in lights),
            half_size=float(scene.floor_half_size),
            environment_scale=float(scene.environment_scale),
        )


class FabricGenParams(StrictModel):
    """Parameters of ``generate.fabric``; unset fields take the preset's values.

    ========================  ==================  ===========  ===========  ================
    name                      type                small        paper        meaning
    ========================  ==================  ===========  ===========  ================
    ``preset``                see below           (default)                 defaults below
    ``patterns``              list of names       plain,       the seven    weave patterns
                                                  twill_3x3,   of Sec. 5.1
                                                  satin_5x5
    ``texture_sets``          int                 1            9 plain, 4   (psi, u) draws
    ``shading_sets``          int                 1            9 plain, 16  (alpha, beta)
    ``queries_per_material``  int                 1280         3276800      queries
    ``samples``               int                 256          2048         per query
    ``sampler``               independent|sobol   sobol        sobol
    ``shard_queries``         int                 640          65536        per shard
    ``map_resolution``        int                 64           256          EXR maps, px
    ``backend``               drjit | numpy       drjit        drjit        estimator
    ``btdf_fraction``         float               0.5          0.5          light below
    ``sizes``                 strata|log_uniform  strata       strata       size design
    ``scene``                 scene (below)       none         none         queries drawn
                                                                            for a render
    ``yarn_profile``          smooth | jin        smooth       smooth       yarn height
                                                                            (yarn.py)
    ========================  ==================  ===========  ===========  ================

    The ``unseen_small``, ``unseen`` and ``unseen_paper`` presets hold sets out for
    ``train.fabric`` (each material's ``split`` in ``materials.json``, by
    :func:`material_split`): the seven training patterns and the unseen twill 4x4; 1 x 2
    sets of plain, twill 3x3, satin 5x5 and twill 4x4 at 256 queries x 64 samples
    (seconds), 4 x 4 sets per training pattern and 2 x 2 of twill 4x4 at 20,480 queries x
    256 samples (116 materials), or Sec. 5.1's sets (9 x 9 plain, 4 x 16 others, 4 x 4
    twill 4x4) at 3.28 M queries x 2,048 samples (481 materials, for a cluster).

    ``scene`` (:class:`FabricScene`) draws the sizes and directions from the render the
    data is meant for (issue 13 section 5; :mod:`generators.fabric.scene_queries`): each
    query takes a pixel whose centre ray hits the floor, the pixel's footprint size (ray
    differentials one pixel apart, tile units, as the fabric BSDFs measure it), the view
    towards the camera, and a light direction from the scene's emitters in proportion to
    their irradiance at that point (the environment map by texel, ``Y(L) |cos|``); centres
    keep the 8 x 8 strata. With ``scene`` set, ``sizes`` and ``btdf_fraction`` must be left
    at their defaults (the scene decides both).

    ==================  ==================  ==============  ==============================
    ``scene`` field     type                default         meaning
    ==================  ==================  ==============  ==============================
    ``name``            floor scene         (required)      ``cloth_plane``,
                                                            ``plane_points``
    ``resolution``      ``[w, h]``          ``[256, 256]``  the render's image, 8..1024
    ``tiles_per_uv``    float               16              the fabric material's
    ``camera``          camera              the scene's     as ``render``'s ``camera``
    ``lights``          point lights        the scene's     as ``render``'s ``lights``
    ==================  ==================  ==============  ==============================

    Examples::

        {"kind": "generate.fabric", "seed": 1, "params": {"preset": "small",
         "patterns": ["twill_5x5"], "samples": 512}}
        {"kind": "generate.fabric", "seed": 1, "params": {"preset": "small",
         "scene": {"name": "cloth_plane", "resolution": [256, 256], "tiles_per_uv": 16}}}
    """

    preset: PresetName = Field(
        default="small",
        description="Named defaults: 'small' (3 materials, one per weave family, 1280 "
        "queries each), 'paper' (Sec. 5.1: 465 materials, 3.28 M queries each) or 'beta' "
        "(per weave family, shading_sets materials (16) that differ only in beta, evenly "
        "spaced over 0.1-1; alpha, w, albedos and geometry held, and one query set: the same "
        "queries and footprint samples for every beta), or with held-out sets for "
        "train.fabric (each material's split in materials.json: train, unseen_material = "
        "the last shading set of each texture set, unseen_pattern = twill_4x4): "
        "'unseen_small' (8 materials, seconds), 'unseen' (the seven training patterns x 4 "
        "texture x 4 shading sets + 4 twill 4x4 = 116 materials, 20,480 queries x 256 "
        "samples) or 'unseen_paper' (Sec. 5.1's 465 + 16 twill 4x4, "
        "3.28 M queries x 2,048 samples; for a cluster).",
    )
    patterns: list[str] | None = Field(
        default=None,
        min_length=1,
        max_length=len(PATTERNS),
        description="Weave patterns by name (materials.fabric.patterns): "
        + ", ".join(PATTERNS)
        + ". Default: the preset's.",
    )
    texture_sets: int | None = Field(
        default=None,
        ge=1,
        le=64,
        description="Yarn-geometry draws (twist psi, inclination u) per pattern, i.e. "
        "normal/orientation textures. Default: the preset's (paper: 9 plain, 4 others).",
    )
    shading_sets: int | None = Field(
        default=None,
        ge=1,
        le=64,
        description="Draws of roughness alpha and height scaling beta (with w and albedos) "
        "per texture set. Default: the preset's (paper: 9 plain, 16 others).",
    )
    queries_per_material: int | None = Field(
        default=None,
        ge=1,
        le=MAX_QUERIES,
        description="Stratified queries per material (generators.fabric.queries); a "
        "multiple of 20480 completes every stratum round. Default: the preset's.",
    )
    samples: int | None = Field(
        default=None,
        ge=8,
        le=1 << 16,
        description="Footprint samples per query (sobol: 4 times a power of two). "
        "Default: 256 (small), 2048 (paper).",
    )
    sampler: Literal["independent", "sobol"] = Field(
        default="sobol",
        description="Footprint sample points: 'independent' uniform, or 'sobol' (scrambled, "
        "per-query digital shifts, 4 replicates for the standard error); both seeded.",
    )
    shard_queries: int | None = Field(
        default=None,
        ge=16,
        le=1 << 20,
        description="Queries per shard (one shard-XXXX.npz, one unit of work and of crash "
        "recovery). Default: 640 (small), 65536 (paper).",
    )
    map_resolution: int | None = Field(
        default=None,
        ge=8,
        le=2048,
        description="Pixels per side of the per-material normal and orientation EXR maps "
        "(one tile). Default: 64 (small), 256 (paper).",
    )
    backend: Literal["drjit", "numpy"] = Field(
        default="drjit",
        description="Estimator backend: 'drjit' (one fused Dr.Jit kernel, LLVM or CUDA as "
        "MATFORGE_VARIANT says) or 'numpy' (reference).",
    )
    btdf_fraction: float = Field(
        default=BTDF_FRACTION,
        ge=0.0,
        le=1.0,
        description="Fraction of direction pairs with the light below the cloth (BTDF "
        "pairs); the rest are BRDF pairs.",
    )

    sizes: Literal["strata", "log_uniform"] = Field(
        default="strata",
        description="Footprint size design: 'strata' (Sec. 5.1: 10 strata over [0, 1] tile "
        f"and 10 over [1, 5]) or 'log_uniform' (20 strata equal in ln size over "
        f"[{LOG_SIZE_MIN:g}, 5] tiles: about a fifth of the queries at a render's 0.03-0.1 "
        "tile pixel footprints, against 1/20 below 0.1 tile). Leave out with 'scene'.",
    )
    scene: FabricScene | None = Field(
        default=None,
        description="Draw the queries for a render: sizes from its pixel footprints, views "
        'from its camera, lights from its emitters (e.g. {"name": "cloth_plane", '
        '"resolution": [256, 256], "tiles_per_uv": 16}). Default: none (the design of '
        "'sizes').",
    )

    yarn_profile: Literal["smooth", "jin"] = Field(
        default="smooth",
        description="Yarn height profile of every material: 'smooth' (the default) tapers "
        "each float's height to zero over its outer half, which makes a different yarn from "
        "Jin et al. 2022's (their normals only on the inner quarter of a float's area); "
        "'jin' keeps Jin's slopes on 90 % of each float and closes the height to zero in a "
        "thin band at its boundary (still watertight). Specs without it keep their artifacts' "
        "bytes.",
    )

    @field_validator("patterns")
    @classmethod
    def _known_patterns(cls, value: list[str] | None) -> list[str] | None:
        if value is None:
            return None
        for name in value:
            if name not in PATTERNS:
                raise _invalid(f"unknown pattern {name!r}; known: {', '.join(sorted(PATTERNS))}")
        if len(set(value)) != len(value):
            raise _invalid("patterns must not repeat")
        return value

    @model_validator(mode="after")
    def _check(self) -> FabricGenParams:
        if self.scene is not None:
            # Specs are re-validated from their dump (defaults filled in), so a field left
            # out and one set to its default are alike here: only other values conflict.
            for name, default in (("sizes", "strata"), ("btdf_fraction", BTDF_FRACTION)):
                if getattr(self, name) != default:
                    raise _invalid(
                        f"{name}: leave it out with scene (the scene's pixels and lights "
                        "decide the sizes and the light's side)"
                    )
        try:
            check_sampling(self.sampler, self.resolved().samples, REPLICATES)
        except ValueError as exc:
            raise _invalid(f"samples: {exc}") from None
        n = len(plan_sets(self.resolved()))
        if n > MAX_MATERIALS:
            raise _invalid(f"at most {MAX_MATERIALS} materials per job, got {n}")
        return self

    def effective(self) -> FabricPreset:
        """The preset with the set fields in its place, but for the set counts (a field is
        one count, a preset a per-pattern table): :meth:`resolved` applies those."""
        return resolve_preset(self, PRESETS, keep=("texture_sets", "shading_sets"))

    def resolved(self) -> Resolved:
        """The effective configuration: explicit fields over the preset's."""
        # The set counts: a field is one count for all patterns, a preset a per-pattern table.
        eff = self.effective()
        patterns = eff.patterns

        def sets(field: int | None, table: dict[str, int]) -> dict[str, int]:
            if field is not None:
                return {p: field for p in patterns}
            return {p: table.get(p, table["*"]) for p in patterns}

        return Resolved(
            patterns=patterns,
            texture_sets=sets(self.texture_sets, eff.texture_sets),
            shading_sets=sets(self.shading_sets, eff.shading_sets),
            queries=eff.queries_per_material,
            samples=eff.samples,
            sampler=self.sampler,
            shard_queries=eff.shard_queries,
            map_resolution=eff.map_resolution,
            backend=self.backend,
            btdf_fraction=self.btdf_fraction,
            sizes=self.sizes,
            scene=None if self.scene is None else self.scene.design(),
            beta_sweep=eff.beta_sweep,
            splits=eff.splits,
            yarn_profile=self.yarn_profile,
        )


@dataclass(frozen=True)
class Resolved:
    """Effective parameters of one job (see :class:`FabricGenParams`)."""

    patterns: tuple[str, ...]
    texture_sets: dict[str, int]
    shading_sets: dict[str, int]
    queries: int
    samples: int
    sampler: str
    shard_queries: int
    map_resolution: int
    backend: str
    btdf_fraction: float
    sizes: str = "strata"
    scene: SceneDesign | None = None
    beta_sweep: bool = False
    yarn_profile: str = "smooth"
    splits: bool = False


def scene_record(scene: SceneDesign) -> dict[str, Any]:
    """A resolved scene as plain JSON data (``materials.json``'s ``config.scene``)."""
    origin, target, up, fov = scene.camera
    return {
        "name": scene.name,
        "resolution": list(scene.resolution),
        "tiles_per_uv": scene.tiles_per_uv,
        "camera": {"origin": list(origin), "target": list(target), "up": list(up), "fov": fov},
        "lights": [{"position": list(p), "intensity": list(i)} for p, i in scene.lights],
        "floor_half_size": scene.half_size,
        "environment_scale": scene.environment_scale,
        "hit_pixels": len(pixel_footprints(scene)),
    }


def sweep_beta(k: int, n: int) -> float:
    """The ``beta`` preset's ``k``-th of ``n`` values: evenly spaced over :data:`BETA_SWEEP`,
    both ends included (the lower end alone when ``n == 1``)."""
    lo, hi = BETA_SWEEP
    return lo if n == 1 else lo + (hi - lo) * k / (n - 1)


def plan_sets(cfg: Resolved) -> list[tuple[str, int, int]]:
    """``(pattern, texture set, shading set)`` of every material, in artifact order."""
    return [
        (name, j, k)
        for name in cfg.patterns
        for j in range(cfg.texture_sets[name])
        for k in range(cfg.shading_sets[name])
    ]
