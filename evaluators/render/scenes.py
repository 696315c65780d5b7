"""Built-in scenes for reference renders, as Mitsuba 3 scene dicts.

World frame: right-handed, **y up**, lengths in scene units (the sphere has radius 1).
Radiometry: environment maps in radiance (W sr^-1 m^-2), point lights in radiant intensity
(W sr^-1), linear Rec. 709 RGB throughout.

================  =========================================================================
scene             what it is
================  =========================================================================
``sphere_env``    a unit sphere at the origin lit by :func:`studio_envmap` (sky, ground and
                  three small bright "studio" lights), seen from +z; the look of the sphere
                  renders in BRDF papers
``sphere_points`` the same sphere and camera under three point lights, black background
``plane_points``  an 8x8 square in the y = 0 plane with uv coordinates in [0, 1]^2 (for
                  textured BTF, glint and fabric materials; u along +x, v along -z)
                  filling the view, seen from 45 degrees above the plane, under three
                  point lights; a ``{"btf_surface": ...}`` material replaces the square
                  with its relief mesh (as does ``cloth_plane``)
``cloth_plane``   a 3x3 square of cloth (uv in [0, 1]^2) in the y = 0 plane under
                  :func:`studio_envmap` plus one warm point light, seen from about 40
                  degrees above it (for ``{"fabric": ...}``: the map's ground lights the
                  cloth from below, through it)
``bent_quad``     Xing et al.'s bent quad: a 3x3 sheet bent about the z axis through 100
                  degrees (uv in [0, 1]^2), under four sharp point lights and a dim
                  :func:`studio_envmap` (for ``{"glint": ...}``, Figs. 5, 8, 9)
``glint_sphere``  the unit sphere (Mitsuba's uv) under the same four point lights and dim
                  environment (Fig. 8's sphere)
``glint_closeup`` the bent quad's apex seen from 0.5 units (40 degrees above it, 30 degree
                  field of view) under two point lights placed about its mirror direction,
                  no environment: at 2048 texels per uv about 2-4 example texels per pixel
                  at 96x72 to 128x96, where single glints resolve
================  =========================================================================

Every scene uses a ``perspective`` camera, an ``hdrfilm`` with a **box** reconstruction
filter, an ``independent`` sampler and the ``path`` integrator. The box filter is a choice
for reproducibility: each sample lands in exactly one pixel, so Mitsuba's LLVM backend
accumulates pixels in a fixed order and the same seed gives the same bytes. A Gaussian filter
splats samples into neighbouring pixels with atomic adds whose order varies from run to run.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import Field, StrictFloat, model_validator

from evaluators.render.btf.relief import relief_mesh
from evaluators.render.meshes import grid_faces, triangle_mesh
from jobapi.params import StrictModel

Vec3 = Annotated[tuple[StrictFloat, StrictFloat, StrictFloat], Field(strict=False)]
NonNegative = Annotated[float, Field(ge=0.0, le=1e9, allow_inf_nan=False)]
RGB = Annotated[tuple[NonNegative, NonNegative, NonNegative], Field(strict=False)]


class PointLight(StrictModel):
    """An isotropic point light."""

    position: Vec3 = Field(description="Position in world units (y up).")
    intensity: RGB = Field(description="Radiant intensity per RGB channel, W/sr (linear).")


class Camera(StrictModel):
    """A pinhole camera looking from ``origin`` at ``target``."""

    origin: Vec3 = Field(description="Eye position in world units (y up).")
    target: Vec3 = Field(description="Point the camera looks at.")
    up: Vec3 = Field(
        default=(0.0, 1.0, 0.0), description="Up direction (not parallel to the viewing direction)."
    )
    fov: float = Field(
        default=35.0,
        gt=1.0,
        lt=170.0,
        allow_inf_nan=False,
        description="Field of view in degrees, along the image's smaller side.",
    )

    @model_validator(mode="after")
    def _check_frame(self) -> Camera:
        view = np.subtract(self.target, self.origin)
        if float(np.linalg.norm(view)) < 1e-6:
            raise ValueError("camera origin and target must differ")
        cross = np.cross(view / np.linalg.norm(view), self.up)
        if float(np.linalg.norm(self.up)) < 1e-6 or float(np.linalg.norm(cross)) < 1e-6:
            raise ValueError("camera up must be non-zero and not parallel to target - origin")
        return self


@dataclass(frozen=True)
class SceneSetup:
    """Everything a scene builder needs besides the BSDF.

    ``resolution`` is ``(width, height)`` in pixels; ``spp`` the samples per pixel of one
    ``mi.render`` call; ``lights``/``camera`` override the scene's defaults when not ``None``.
    """

    resolution: tuple[int, int]
    spp: int
    max_depth: int
    lights: tuple[PointLight, ...] | None = None
    camera: Camera | None = None


# -- the studio environment map ------------------------------------------------------------

# (direction towards the light, angular radius in degrees, RGB radiance): a warm key light
# upper left, a cool fill light right, a rim light behind, as seen from the default camera.
_STUDIO_LIGHTS: tuple[tuple[tuple[float, float, float], float, tuple[float, float, float]], ...] = (
    ((-0.55, 0.65, 0.52), 8.0, (36.0, 33.0, 28.0)),
    ((0.80, 0.15, 0.58), 10.0, (7.0, 8.0, 10.0)),
    ((0.25, 0.55, -0.80), 6.0, (24.0, 24.0, 24.0)),
)
_ZENITH = np.array([0.10, 0.18, 0.42])
_HORIZON = np.array([0.55, 0.58, 0.62])
_GROUND = np.array([0.16, 0.14, 0.12])


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def envmap_directions(width: int, height: int) -> np.ndarray:
    """World directions of the pixel centres of a ``(height, width)`` latitude-longitude map
    in Mitsuba's ``envmap`` convention: ``u = atan2(x, -z) / 2 pi``, ``v = acos(y) / pi``,
    row 0 at the zenith. Returns ``(height, width, 3)`` float64 unit vectors."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    phi, theta = np.meshgrid(2.0 * np.pi * u, np.pi * v)
    return np.stack(
        [np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], axis=-1
    )


def studio_envmap(width: int = 512, height: int = 256) -> np.ndarray:
    """matforge's HDR studio environment, made from code (deterministic, no files).

    A sky whose radiance blends from a bright horizon to a blue zenith, a darker warm ground,
    a soft horizon line, and three small bright disc lights with smooth edges (key, fill and
    rim; up to 36 W sr^-1 m^-2 against a sky below 0.7). Returns ``(height, width, 3)``
    float32 linear RGB radiance in Mitsuba's envmap layout (:func:`envmap_directions`).
    """
    if width < 8 or height < 4:
        raise ValueError(f"envmap too small: {width}x{height}")
    d = envmap_directions(width, height)
    y = d[..., 1:2]
    sky_t = np.sqrt(np.clip(y, 0.0, 1.0))
    sky = (1.0 - sky_t) * _HORIZON + sky_t * _ZENITH
    ground = _GROUND * (0.6 + 0.4 * np.clip(1.0 + y, 0.0, 1.0))
    blend = _smoothstep(-0.02, 0.02, y)
    radiance = blend * sky + (1.0 - blend) * ground
    for direction, radius_deg, rgb in _STUDIO_LIGHTS:
        axis = np.asarray(direction) / np.linalg.norm(direction)
        angle = np.degrees(np.arccos(np.clip(d @ axis, -1.0, 1.0)))[..., None]
        disc = 1.0 - _smoothstep(0.8 * radius_deg, radius_deg, angle)
        radiance = radiance + disc * np.asarray(rgb)
    return np.ascontiguousarray(radiance, dtype=np.float32)


# -- scene dicts ---------------------------------------------------------------------------


def _sensor(
    mi: types.ModuleType, cam: Camera, resolution: tuple[int, int], spp: int
) -> dict[str, Any]:
    width, height = resolution
    return {
        "type": "perspective",
        "fov": float(cam.fov),
        "fov_axis": "smaller",
        "to_world": mi.ScalarTransform4f().look_at(
            origin=list(cam.origin), target=list(cam.target), up=list(cam.up)
        ),
        "film": {
            "type": "hdrfilm",
            "width": int(width),
            "height": int(height),
            "pixel_format": "rgb",
            "component_format": "float32",
            "rfilter": {"type": "box"},
        },
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }


def _point_lights(lights: tuple[PointLight, ...]) -> dict[str, Any]:
    return {
        f"light_{i}": {
            "type": "point",
            "position": list(light.position),
            "intensity": {"type": "rgb", "value": list(light.intensity)},
        }
        for i, light in enumerate(lights)
    }


def _base(
    mi: types.ModuleType, camera: Camera, max_depth: int, resolution: tuple[int, int], spp: int
) -> dict[str, Any]:
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth)},
        "sensor": _sensor(mi, camera, resolution, spp),
    }


SPHERE_CAMERA = Camera(origin=(0.0, 0.0, 4.0), target=(0.0, 0.0, 0.0), fov=35.0)
PLANE_CAMERA = Camera(origin=(0.0, 3.2, 3.2), target=(0.0, 0.0, 0.0), fov=40.0)
SPHERE_LIGHTS = (
    PointLight(position=(-3.0, 3.0, 3.0), intensity=(32.0, 30.0, 28.0)),
    PointLight(position=(3.5, 1.0, 3.0), intensity=(9.0, 10.0, 11.0)),
    PointLight(position=(1.0, 3.0, -3.5), intensity=(18.0, 18.0, 18.0)),
)
#: Half the side of the ``plane_points`` square: large enough to fill the default view.
PLANE_HALF_SIZE = 4.0
PLANE_LIGHTS = (
    PointLight(position=(-2.0, 2.0, 1.0), intensity=(12.0, 11.0, 10.0)),
    PointLight(position=(2.5, 1.5, 2.0), intensity=(4.0, 4.5, 5.0)),
    PointLight(position=(0.5, 2.0, -2.0), intensity=(8.0, 8.0, 8.0)),
)


def _environment(mi: types.ModuleType, scale: float) -> dict[str, Any]:
    return {"type": "envmap", "bitmap": mi.Bitmap(studio_envmap()), "scale": scale}


@dataclass(frozen=True)
class LitScene:
    """A scene builder (:attr:`SceneDef.builder`): the integrator and sensor of
    :func:`_base`, the shapes ``shapes(mi, bsdf)``, :func:`studio_envmap` at
    ``environment_scale`` (0: no environment) and the point lights ``lights``."""

    shapes: Callable[[types.ModuleType, Any], dict[str, Any]]
    environment_scale: float = 0.0

    def __call__(
        self,
        mi: types.ModuleType,
        bsdf: Any,
        camera: Camera,
        lights: tuple[PointLight, ...],
        max_depth: int,
        resolution: tuple[int, int],
        spp: int,
    ) -> dict[str, Any]:
        scene = _base(mi, camera, max_depth, resolution, spp)
        scene.update(self.shapes(mi, bsdf))
        if self.environment_scale:
            scene["environment"] = _environment(mi, self.environment_scale)
        scene.update(_point_lights(lights))
        return scene


def _sphere(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    """The unit sphere at the origin, Mitsuba's orientation (pole on +z)."""
    return {"sphere": {"type": "sphere", "bsdf": bsdf}}


def _upright_sphere(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    """The unit sphere with its pole up (+y) and its uv seam (``phi = 0``) away from the
    default camera.

    Mitsuba's sphere has its pole on local +z, which would face the camera, and a texture (a
    BTF, Xu et al. Fig. 17's sphere) would converge to a pinwheel at the centre of the view.
    Rotations leave the geometry, and so isotropic materials, unchanged.
    """
    return {
        "sphere": {
            "type": "sphere",
            "bsdf": bsdf,
            # Applied right to left: local +z (pole) to +y, then local +x (seam) to -z.
            "to_world": mi.ScalarTransform4f()
            .rotate([0.0, 1.0, 0.0], 90.0)
            .rotate([1.0, 0.0, 0.0], -90.0),
        }
    }


#: Unit sphere under :func:`studio_envmap`, plus ``lights`` (none by default).
sphere_env = LitScene(_sphere, environment_scale=1.0)
#: Unit sphere (:func:`_upright_sphere`) under point lights (by default
#: :data:`SPHERE_LIGHTS`), black background.
sphere_points = LitScene(_upright_sphere)


def floor_under_sphere(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    """A floor of ``bsdf`` under the unit sphere of ``sphere_env``, for interreflections: a
    square of side 8 in y = -1, normal +y (add it to the scene dict as ``"floor"``)."""
    return {
        "type": "rectangle",
        "bsdf": bsdf,
        "to_world": mi.ScalarTransform4f()
        .translate([0.0, -1.0, 0.0])
        .rotate([1.0, 0.0, 0.0], -90.0)
        .scale(4.0),
    }


def _floor_square(mi: types.ModuleType, bsdf: Any, half_size: float) -> Any:
    """A square of side ``2 half_size`` in y = 0, normal +y, uv in [0, 1]^2 (u along +x,
    v along -z; shading frame ``(dp/du, dp/dv, n)``).

    Mitsuba's rectangle spans [-1, 1]^2 in z = 0 with normal +z: rotated into y = 0. A BSDF
    carrying a ``relief`` (``{"btf_surface": ...}``) gets the relief mesh of
    :func:`evaluators.render.btf.relief.relief_mesh` over the same square instead, with the
    BSDF it wraps.
    """
    relief = getattr(bsdf, "relief", None)
    if relief is not None:
        return relief_mesh(mi, relief, half_size, bsdf.inner)
    return {
        "type": "rectangle",
        "bsdf": bsdf,
        "to_world": mi.ScalarTransform4f()
        .rotate([1.0, 0.0, 0.0], -90.0)
        .scale([half_size, half_size, 1.0]),
    }


def _plane(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    return {"plane": _floor_square(mi, bsdf, PLANE_HALF_SIZE)}


#: An 8x8 textured square (normal +y, uv in [0, 1]^2) under point lights.
plane_points = LitScene(_plane)


#: Half the side of the ``cloth_plane`` square.
CLOTH_HALF_SIZE = 1.5
CLOTH_CAMERA = Camera(origin=(0.0, 2.0, 2.4), target=(0.0, 0.0, 0.0), fov=45.0)
CLOTH_LIGHTS = (PointLight(position=(-1.5, 2.5, 1.0), intensity=(6.0, 5.5, 5.0)),)


def _cloth(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    return {"cloth": _floor_square(mi, bsdf, CLOTH_HALF_SIZE)}


#: A 3x3 square (normal +y, uv in [0, 1]^2) under :func:`studio_envmap` and ``lights``.
cloth_plane = LitScene(_cloth, environment_scale=1.0)


#: Four sharp point lights, as in Xing et al. 2024's scenes.
GLINT_LIGHTS = (
    PointLight(position=(-2.5, 3.0, 2.0), intensity=(40.0, 38.0, 36.0)),
    PointLight(position=(2.5, 2.5, 2.5), intensity=(20.0, 22.0, 24.0)),
    PointLight(position=(0.5, 3.5, -2.0), intensity=(25.0, 25.0, 25.0)),
    PointLight(position=(-1.0, 1.5, 3.5), intensity=(12.0, 12.0, 12.0)),
)
BENT_CAMERA = Camera(origin=(0.0, 2.2, 3.6), target=(0.0, -0.3, 0.0), fov=45.0)
#: Scale of the environment behind the glint scenes (the point lights carry the glints).
GLINT_ENV_SCALE = 0.25


def bent_quad_mesh(mi: types.ModuleType, bsdf: Any, segments: int = 32) -> Any:
    """A 3 x 3 sheet bent about the z axis through 100 degrees on a radius of 2, apex at the
    origin, normal up; uv in [0, 1]^2 (u along the bend). A ``mi.Mesh`` carrying ``bsdf``."""
    nu, nv = segments, 4
    u, v = np.linspace(0.0, 1.0, nu + 1), np.linspace(0.0, 1.0, nv + 1)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    ang = (uu - 0.5) * np.radians(100.0)
    radius = 1.5 / np.radians(50.0)  # arc length 3
    pos = np.stack(
        [radius * np.sin(ang), radius * (np.cos(ang) - 1.0), (0.5 - vv) * 3.0], axis=-1
    ).reshape(-1, 3)
    nrm = np.stack([np.sin(ang), np.cos(ang), np.zeros_like(ang)], axis=-1).reshape(-1, 3)
    uv = np.stack([uu, vv], axis=-1).reshape(-1, 2)
    faces = grid_faces(nu + 1, nv + 1)
    return triangle_mesh(mi, "bent_quad", pos, faces, bsdf, uv=uv, normals=nrm)


def _quad(mi: types.ModuleType, bsdf: Any) -> dict[str, Any]:
    return {"quad": bent_quad_mesh(mi, bsdf)}


#: The bent quad under ``lights`` (by default :data:`GLINT_LIGHTS`) and a dim map.
bent_quad = LitScene(_quad, environment_scale=GLINT_ENV_SCALE)
#: The unit sphere under ``lights`` (by default :data:`GLINT_LIGHTS`) and a dim map.
glint_sphere = LitScene(_sphere, environment_scale=GLINT_ENV_SCALE)


_CLOSEUP_ELEVATION = math.radians(40.0)
#: The close-up's camera: 0.5 units from the bent quad's apex, 40 degrees above it. The
#: image's short side spans 2 * 0.5 * tan(15 deg) = 0.27 units, i.e. 0.089 uv (184 texels at
#: 2048 per uv): 1.9 texels per pixel across at 96 rows, 2.5 at 72 (times 1.56 along v,
#: foreshortened).
CLOSEUP_CAMERA = Camera(
    origin=(0.0, 0.5 * math.sin(_CLOSEUP_ELEVATION), 0.5 * math.cos(_CLOSEUP_ELEVATION)),
    target=(0.0, 0.0, 0.0),
    fov=30.0,
)
#: Two point lights about the camera's mirror direction at the apex (3 units away), so that
#: the highlight's glints fill the view; the second off to one side, dimmer.
CLOSEUP_LIGHTS = (
    PointLight(
        position=(0.0, 3.0 * math.sin(_CLOSEUP_ELEVATION), -3.0 * math.cos(_CLOSEUP_ELEVATION)),
        intensity=(20.0, 19.0, 18.0),
    ),
    PointLight(position=(0.5, 2.4, -1.8), intensity=(8.0, 9.0, 10.0)),
)


#: The bent quad close up under ``lights`` (by default :data:`CLOSEUP_LIGHTS`) and no
#: environment: the point lights carry the glints, and an environment reached through the
#: BSDF's sampling would add Monte Carlo speckle that no microstructure puts there.
glint_closeup = LitScene(_quad)


@dataclass(frozen=True)
class SceneDef:
    """A built-in scene: its builder and its default camera and point lights."""

    builder: Callable[..., dict[str, Any]]
    camera: Camera
    lights: tuple[PointLight, ...]
    summary: str
    #: Whether the scene replaces its floor by a BSDF's ``relief`` (``btf_surface``).
    relief: bool = False
    #: Half the side of the scene's material square when it is the y = 0 floor of
    #: :func:`_floor_square` (uv in [0, 1]^2, u along +x, v along -z), else ``None``; read
    #: by ``generate.fabric``'s scene-driven queries (``generators/fabric/scene_queries.py``).
    floor_half_size: float | None = None
    #: Scale of the :func:`studio_envmap` environment the builder adds (0: none).
    environment_scale: float = 0.0

    def camera_for(self, setup: SceneSetup) -> Camera:
        """The camera used with ``setup`` (its override, or the default)."""
        return setup.camera or self.camera

    def lights_for(self, setup: SceneSetup) -> tuple[PointLight, ...]:
        """The point lights used with ``setup`` (its override, or the defaults)."""
        return self.lights if setup.lights is None else tuple(setup.lights)


#: The built-in scenes, by name.
SCENES: dict[str, SceneDef] = {
    "sphere_env": SceneDef(
        sphere_env,
        SPHERE_CAMERA,
        (),
        "unit sphere under matforge's HDR studio environment map",
        environment_scale=1.0,
    ),
    "sphere_points": SceneDef(
        sphere_points, SPHERE_CAMERA, SPHERE_LIGHTS, "unit sphere under three point lights"
    ),
    "plane_points": SceneDef(
        plane_points,
        PLANE_CAMERA,
        PLANE_LIGHTS,
        "textured plane seen at an angle, three point lights",
        relief=True,
        floor_half_size=PLANE_HALF_SIZE,
    ),
    "cloth_plane": SceneDef(
        cloth_plane,
        CLOTH_CAMERA,
        CLOTH_LIGHTS,
        "square of cloth under the studio environment map and a point light",
        relief=True,
        floor_half_size=CLOTH_HALF_SIZE,
        environment_scale=1.0,
    ),
    "bent_quad": SceneDef(
        bent_quad,
        BENT_CAMERA,
        GLINT_LIGHTS,
        "bent quad under four point lights, dim map",
        environment_scale=GLINT_ENV_SCALE,
    ),
    "glint_sphere": SceneDef(
        glint_sphere,
        SPHERE_CAMERA,
        GLINT_LIGHTS,
        "unit sphere under four point lights, dim map",
        environment_scale=GLINT_ENV_SCALE,
    ),
    "glint_closeup": SceneDef(
        glint_closeup,
        CLOSEUP_CAMERA,
        CLOSEUP_LIGHTS,
        "close-up of the bent quad's apex under two point lights, no environment",
    ),
}


def build_scene(name: str, mi: types.ModuleType, bsdf: Any, setup: SceneSetup) -> dict[str, Any]:
    """The Mitsuba scene dict of the built-in scene ``name`` with ``bsdf`` on its object.

    ``bsdf`` is a Mitsuba BSDF plugin dict or an instantiated ``mi.BSDF``. A BSDF with a
    ``relief`` (geometry of its own) is refused, with a ``ValueError``, by scenes that
    cannot replace their object with it.
    """
    try:
        scene = SCENES[name]
    except KeyError:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}") from None
    if getattr(bsdf, "relief", None) is not None and not scene.relief:
        floors = ", ".join(k for k, v in SCENES.items() if v.relief)
        raise ValueError(
            f"this material is a surface with relief (geometry), which the scene {name!r} "
            f"cannot show; render it in {floors}"
        )
    if setup.spp < 1 or setup.max_depth < 1 or min(setup.resolution) < 1:
        raise ValueError(f"invalid scene setup {setup}")
    return scene.builder(
        mi,
        bsdf,
        scene.camera_for(setup),
        scene.lights_for(setup),
        setup.max_depth,
        setup.resolution,
        setup.spp,
    )
