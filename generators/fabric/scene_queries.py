"""Scene-driven queries for ``generate.fabric``: footprints and directions a render will ask.

Issue 12 part 3 and issue 13 section 5 ("model no more than a scene needs"): instead of the
Sec. 5.1 design's sizes and cosine-distributed directions, a material's queries are drawn
from the scene it is meant for. Only scenes whose material sits on the y = 0 floor square
(:attr:`evaluators.render.scenes.SceneDef.floor_half_size`: ``cloth_plane``,
``plane_points``) are supported: the footprint of a plane seen through a pinhole is exact in
closed form, and the flat floor has one shading frame everywhere.

- **Pixels.** The camera ray through each pixel's *centre* (as the ``fabric_path``
  integrator traces it, :mod:`evaluators.render.integrators.fabric_path`) is intersected with
  the floor; the pixels whose ray hits the square are the scene's queries' pool. A query
  takes a pixel by the same round-by-round stratification as the Sec. 5.1 factors
  (:mod:`generators.fabric.queries`): every complete round visits each hit pixel once, so
  each pixel, i.e. each share of the image that FLIP and MSE average over, weighs the same.
- **Footprint size** (tile units), as the renderer defines it: the ray differentials one
  pixel apart in x and y (Mitsuba's ``perspective`` sensor, ``sample_ray_differential``,
  whose rays all start at the main ray's point on the near plane, :data:`NEAR_CLIP`) meet
  the floor's tangent plane, which for the floor is the floor itself, at ``p + dp_dx`` and
  ``p + dp_dy``; ``si.compute_uv_partials`` turns them into ``duv_dx``, ``duv_dy`` with
  ``u = (x + h) / 2h`` and ``v`` along ``-z``; the fabric BSDFs scale them by
  ``tiles_per_uv`` (``t`` also by the tile's aspect ``w / h``,
  :mod:`evaluators.render.bsdfs.fabric_footprint`), and the network's square is
  ``size = sqrt(|det|)`` of that parallelogram (:mod:`evaluators.render.bsdfs.fabric_model`).
  Sizes are clipped to 5 tiles, where the network's decoder clamps them too.
- **View** ``wo``: from the pixel's hit point towards the camera's origin, in the floor's
  shading frame ``(dp/du, dp/dv, n) = (+x, -z, +y)``.
- **Light** ``wi``, at the pixel's hit point: one of the scene's emitters, chosen with
  probability proportional to its irradiance there (luminance, Rec. 709), then a direction
  from it: a point light's direction to the point; for the environment map (``cloth_plane``:
  :func:`evaluators.render.scenes.studio_envmap`), a texel with probability proportional to
  ``Y(L) |cos theta_n| dOmega`` and a uniform point in it. Why that density: the pixel's
  radiance is ``int f_P(wi, wo) L(wi) dwi`` with the cosine inside ``f_P``; for an error that
  is a fixed fraction of ``f_P`` (how a network's error behaves) and a diffuse-like lobe, a
  direction's share of the pixel's error is its share of the irradiance, ``L |cos|``. So the
  bright studio discs and the point light get most pairs, the sky the rest, and the ground
  below the horizon (which lights the cloth through it) gives the BTDF pairs (``wi_z < 0``),
  in the proportion the scene has them (about a tenth in ``cloth_plane``), not a fixed
  ``btdf_fraction``. Occlusion is ignored: a floor under open sky is never shadowed.
- **Centres** keep the Sec. 5.1 8 x 8 stratification: with ``tiles_per_uv`` tiles across the
  square, pixel centres fall at all phases of the tile alike.

Every factor (pixel, light choice, environment texel) uses its own seeded round-by-round
permutations with jitters, so as in :func:`generators.fabric.queries.design_queries` any range
of queries can be generated alone and a shard's queries do not depend on the shard split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from evaluators.render.scenes import envmap_directions, studio_envmap
from generators.fabric.queries import MIN_Z, QueryBatch, design_centres, factor_cells

#: Rec. 709 luminance weights (linear RGB).
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Largest footprint size given to a query, tile units (the network's decoder clamps here).
MAX_SIZE = 5.0
#: Mitsuba's ``perspective`` near clip distance (the scenes keep its default).
NEAR_CLIP = 1e-2
#: Cells of the stratified light-choice and environment-texel factors per round.
LIGHT_ROUND = 4096

_TAG_PIXEL, _TAG_LIGHT, _TAG_ENV = 0x9F, 0x1A, 0xE7

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class SceneDesign:
    """A resolved scene for the query design (hashable; the shards carry it).

    Lengths in scene units, y up; ``camera`` is ``(origin, target, up, fov_deg)`` with the
    field of view along the image's smaller side, as :class:`evaluators.render.scenes.Camera`;
    ``lights`` are ``(position, rgb intensity W/sr)`` point lights.
    """

    name: str
    resolution: tuple[int, int]
    tiles_per_uv: float
    camera: tuple[Vec3, Vec3, Vec3, float]
    lights: tuple[tuple[Vec3, Vec3], ...]
    half_size: float
    environment_scale: float


@dataclass(frozen=True)
class PixelFootprints:
    """The ``M`` pixels whose centre ray hits the floor square, float64.

    ``pixel`` ``(M, 2)`` int ``(column, row)``, row 0 at the top; ``point`` ``(M, 3)`` world
    hit points; ``duv`` ``(M, 2, 2)`` rows ``duv_dx``, ``duv_dy`` (uv per pixel); ``size_uv``
    ``(M,)`` ``sqrt(|det duv|)``; ``wo`` ``(M, 3)`` unit view directions in the floor's
    shading frame (``z > 0``).
    """

    pixel: np.ndarray
    point: np.ndarray
    duv: np.ndarray
    size_uv: np.ndarray
    wo: np.ndarray

    def __len__(self) -> int:
        return int(self.size_uv.shape[0])


def camera_basis(
    origin: np.ndarray, target: np.ndarray, up: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mitsuba's ``look_at`` frame: camera +x ``left``, +y ``up``, +z ``forward``."""
    forward = (target - origin) / np.linalg.norm(target - origin)
    left = np.cross(up, forward)
    left /= np.linalg.norm(left)
    return left, np.cross(forward, left), forward


def pixel_directions(
    camera: tuple[Vec3, Vec3, Vec3, float],
    resolution: tuple[int, int],
    offset: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """``(H, W, 3)`` unit world directions of the rays through film points ``(i + 0.5 +
    offset_x, j + 0.5 + offset_y)`` pixels (column ``i``, row ``j`` from the top).

    Mitsuba's ``perspective`` sensor (``perspective_projection``): the film's sample
    ``(sx, sy)`` in ``[0, 1]^2`` is the camera-space direction ``((1 - 2 sx) tan(fx / 2),
    (1 - 2 sy) tan(fx / 2) / aspect, 1)``, ``aspect = W / H``, ``fx`` the horizontal field
    of view (``fov_axis = "smaller"``: ``fov`` along ``y`` when ``W >= H``).
    """
    origin, target, up = (np.asarray(v, dtype=np.float64) for v in camera[:3])
    fov = float(camera[3])
    w, h = resolution
    aspect = w / h
    half = math.tan(math.radians(fov) / 2.0)
    tan_x = half * aspect if w >= h else half
    sx = (np.arange(w) + 0.5 + offset[0]) / w
    sy = (np.arange(h) + 0.5 + offset[1]) / h
    x = (1.0 - 2.0 * sx)[None, :] * tan_x
    y = (1.0 - 2.0 * sy)[:, None] * tan_x / aspect
    left, new_up, forward = camera_basis(origin, target, up)
    d = x[..., None] * left + y[..., None] * new_up + forward
    d = np.broadcast_to(d, (h, w, 3))
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def _hit_floor(origin: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hit points ``(..., 3)`` of rays from ``origin`` (``(3,)`` or ``(..., 3)``) on the
    plane ``y = 0``, and whether each ray meets it ahead (``t > 0``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[..., 1] / d[..., 1]
    ok = np.isfinite(t) & (t > 0.0)
    t = np.where(ok, t, 0.0)
    return origin + t[..., None] * d, ok


@lru_cache(maxsize=8)
def pixel_footprints(scene: SceneDesign) -> PixelFootprints:
    """The floor's pixel footprints in ``scene`` (see the module docstring); cached."""
    origin = np.asarray(scene.camera[0], dtype=np.float64)
    h2 = 2.0 * scene.half_size
    d = pixel_directions(scene.camera, scene.resolution)
    p, hit = _hit_floor(origin, d)
    hit &= (np.abs(p[..., 0]) <= scene.half_size) & (np.abs(p[..., 2]) <= scene.half_size)
    # Mitsuba starts a camera ray, and both its offset rays, at the main ray's point on the
    # near plane: the differentials are those of a pinhole NEAR_CLIP in front of the camera
    # (0.3 % smaller footprints in cloth_plane than from the eye itself).
    forward = camera_basis(origin, *(np.asarray(v, float) for v in scene.camera[1:3]))[2]
    near = origin + d * (NEAR_CLIP / (d @ forward))[..., None]
    partials = []
    for offset in ((1.0, 0.0), (0.0, 1.0)):  # sample_ray_differential: one pixel apart
        q, ok = _hit_floor(near, pixel_directions(scene.camera, scene.resolution, offset))
        hit &= ok
        dp = q - p
        partials.append(np.stack([dp[..., 0] / h2, -dp[..., 2] / h2], axis=-1))
    rows, cols = np.nonzero(hit)
    duv = np.stack([partials[0][rows, cols], partials[1][rows, cols]], axis=1)
    det = duv[:, 0, 0] * duv[:, 1, 1] - duv[:, 0, 1] * duv[:, 1, 0]
    point = p[rows, cols]
    view = origin - point
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    return PixelFootprints(
        pixel=np.stack([cols, rows], axis=1),
        point=point,
        duv=duv,
        size_uv=np.sqrt(np.abs(det)),
        wo=to_local(view),
    )


def to_local(d: np.ndarray) -> np.ndarray:
    """World ``(..., 3)`` vectors in the floor's shading frame ``(+x, -z, +y)``."""
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], axis=-1)


@lru_cache(maxsize=2)
def _environment() -> tuple[np.ndarray, np.ndarray, float, tuple[int, int]]:
    """``(directions (T, 3), cdf (T,), irradiance at scale 1, (W, H))`` of the studio map's
    texels, weighted by ``Y(L) |y| dOmega`` (both hemispheres; the floor's normal is +y)."""
    radiance = studio_envmap().astype(np.float64)
    height, width = radiance.shape[:2]
    d = envmap_directions(width, height)
    theta = np.pi * (np.arange(height) + 0.5) / height
    d_omega = (2.0 * np.pi / width) * (np.pi / height) * np.sin(theta)[:, None]
    weight = (radiance @ LUMA) * np.abs(d[..., 1]) * d_omega
    flat = weight.ravel()
    cdf = np.cumsum(flat)
    total = float(cdf[-1])
    return d.reshape(-1, 3), cdf / total, total, (width, height)


def environment_irradiance(scale: float = 1.0) -> float:
    """Luminance irradiance of the studio map on the floor, both sides together (W m^-2)."""
    return scale * _environment()[2]


def _environment_directions(u: np.ndarray, jitter: np.ndarray) -> np.ndarray:
    """World directions ``(N, 3)``: the texel at ``u`` (``(N,)``, inverse CDF) with a
    uniform point in it (``jitter`` ``(N, 2)``), in :func:`envmap_directions`' mapping."""
    _, cdf, _, (width, height) = _environment()
    texel = np.minimum(np.searchsorted(cdf, u, side="right"), cdf.size - 1)
    row, col = np.divmod(texel, width)
    phi = 2.0 * np.pi * (col + jitter[:, 0]) / width
    theta = np.pi * (row + jitter[:, 1]) / height
    return np.stack(
        [np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], axis=1
    )


def light_weights(scene: SceneDesign, point: np.ndarray) -> np.ndarray:
    """``(N, 1 + L)`` luminance irradiance at floor points ``(N, 3)``: the environment map
    (column 0) and each point light (``Y(I) |cos| / r^2``)."""
    cols = [np.full(point.shape[0], environment_irradiance(scene.environment_scale))]
    for position, intensity in scene.lights:
        v = np.asarray(position, dtype=np.float64) - point
        r2 = np.einsum("ij,ij->i", v, v)
        cols.append(float(np.asarray(intensity) @ LUMA) * np.abs(v[:, 1]) / r2**1.5)
    return np.stack(cols, axis=1)


def _stratified(seed: int, tag: int, dims: int, first: int, count: int) -> np.ndarray:
    """``(count, 1 + dims)``: a stratified uniform in column 0 (rounds of
    :data:`LIGHT_ROUND` cells) and ``dims`` plain uniforms."""
    cells, jit, _ = factor_cells(seed, tag, LIGHT_ROUND, 1 + dims, first, count)
    return np.concatenate([((cells + jit[:, 0]) / LIGHT_ROUND)[:, None], jit[:, 1:]], axis=1)


def scene_queries(
    scene: SceneDesign, seed: int, first: int, count: int, *, tile_aspect: float = 1.0
) -> QueryBatch:
    """Queries ``first .. first + count - 1`` of one material drawn from ``scene``.

    Parameters
    ----------
    scene
        The resolved scene (:class:`SceneDesign`).
    seed
        The material's design seed.
    first, count
        The query range; the result does not depend on how a material's range is split.
    tile_aspect
        The pattern's tile width over height (``YarnGeometry.tile``): the fabric BSDFs scale
        ``v`` by ``tiles_per_uv * w / h``, so the footprint's area by that aspect.

    Returns
    -------
    :class:`generators.fabric.queries.QueryBatch`; directions in the floor's shading frame.
    """
    if first < 0 or count < 0:
        raise ValueError(f"first and count must be >= 0, got {first}, {count}")
    fp = pixel_footprints(scene)
    if len(fp) == 0:
        raise ValueError(f"no pixel of scene {scene.name!r} sees its floor")
    centre = design_centres(seed, first, count)
    pix, _, _ = factor_cells(seed, _TAG_PIXEL, len(fp), 0, first, count)
    size = scene.tiles_per_uv * math.sqrt(tile_aspect) * fp.size_uv[pix]
    size = np.minimum(size, MAX_SIZE)
    wo = fp.wo[pix]
    point = fp.point[pix]
    # Which emitter: inverse CDF of the irradiance shares at the point (stratified).
    weights = light_weights(scene, point)
    cdf = np.cumsum(weights, axis=1)
    choice = _stratified(seed, _TAG_LIGHT, 0, first, count)[:, 0] * cdf[:, -1]
    emitter = np.minimum((cdf <= choice[:, None]).sum(axis=1), weights.shape[1] - 1)
    wi_world = np.empty((count, 3))
    env = emitter == 0
    u = _stratified(seed, _TAG_ENV, 2, first, count)
    wi_world[env] = _environment_directions(u[env, 0], u[env, 1:])
    for k, (position, _) in enumerate(scene.lights, start=1):
        mask = emitter == k
        v = np.asarray(position, dtype=np.float64) - point[mask]
        wi_world[mask] = v / np.linalg.norm(v, axis=1, keepdims=True)
    wi = to_local(wi_world)
    # The estimator needs wi_z != 0: keep the side, at least MIN_Z off the plane.
    side = np.where(wi[:, 2] < 0.0, -1.0, 1.0)
    wi[:, 2] = side * np.maximum(np.abs(wi[:, 2]), MIN_Z)
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    return QueryBatch(centre=centre, size=size, wi=wi, wo=wo)
