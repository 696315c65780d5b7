"""Scene-driven queries of ``generate.fabric`` (``generators.fabric.scene_queries``).

Oracles:
- pinhole geometry by hand: a camera looking straight down at height ``H`` with field of
  view ``f`` over ``N`` pixels sees every pixel as a square of side ``2 H tan(f / 2) / N``
  on the floor; a pixel on the optical axis seen at ``theta`` from the normal covers
  ``1 / cos(theta)`` times the area it covers head-on (same distance), and its view is
  ``wo_z = cos(theta)``;
- the renderer itself: Mitsuba's ``perspective`` sensor's ray differentials through pixel
  centres and ``si.compute_uv_partials`` on the built ``cloth_plane`` (what the
  ``fabric_path`` integrator hands the fabric BSDFs);
- inverse projection: each query's view, traced back from the camera, lands on the floor at
  a point the camera projects onto a pixel *centre*;
- brute-force quadrature of the studio map at twice the sampler's resolution for the share
  of light from below (BTDF pairs), and the point light's irradiance share;
- determinism and independence of the range split.
"""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

from evaluators.render.scenes import SCENES, envmap_directions, studio_envmap
from generators.fabric import scene_queries as sq


def _design(
    camera: tuple, resolution: tuple[int, int] = (64, 64), lights: tuple = (), env: float = 1.0
) -> sq.SceneDesign:
    return sq.SceneDesign(
        name="cloth_plane",
        resolution=resolution,
        tiles_per_uv=16.0,
        camera=camera,
        lights=lights,
        half_size=1.5,
        environment_scale=env,
    )


def _cloth(resolution: tuple[int, int] = (64, 64)) -> sq.SceneDesign:
    d = SCENES["cloth_plane"]
    c = d.camera
    assert d.floor_half_size is not None
    return sq.SceneDesign(
        name="cloth_plane",
        resolution=resolution,
        tiles_per_uv=16.0,
        camera=(c.origin, c.target, c.up, c.fov),
        lights=tuple((light.position, light.intensity) for light in d.lights),
        half_size=d.floor_half_size,
        environment_scale=d.environment_scale,
    )


def test01_top_down_footprint_is_the_pinhole_pixel_size() -> None:
    height, fov, n = 2.0, 40.0, 64
    design = _design(((0.0, height, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -1.0), fov), (n, n))
    fp = sq.pixel_footprints(design)
    # World units per pixel. Mitsuba's rays (and their differentials) start on the near
    # plane, NEAR_CLIP in front of the eye: the offset rays spread from there.
    pitch = 2.0 * (height - sq.NEAR_CLIP) * math.tan(math.radians(fov) / 2.0) / n
    eye_pitch = 2.0 * height * math.tan(math.radians(fov) / 2.0) / n  # pixel centres
    side_uv = pitch / (2.0 * 1.5)
    # The floor is parallel to the film: every pixel's footprint is the same square.
    np.testing.assert_allclose(fp.size_uv, side_uv, rtol=1e-9)
    # Image right is +x (u), image down is +z (v along -z): duv_dx = (s, 0), duv_dy = (0, -s).
    np.testing.assert_allclose(fp.duv[:, 0], [[side_uv, 0.0]] * len(fp), atol=1e-12)
    np.testing.assert_allclose(fp.duv[:, 1], [[0.0, -side_uv]] * len(fp), atol=1e-12)
    # Which pixels see the square: their centres' floor points by hand.
    centres = (np.arange(n) + 0.5 - n / 2) * eye_pitch
    inside = np.abs(centres) <= 1.5
    assert len(fp) == inside.sum() ** 2
    np.testing.assert_allclose(fp.wo[:, 2], height / np.linalg.norm(
        np.c_[fp.point[:, 0], np.full(len(fp), height), fp.point[:, 2]], axis=1))  # fmt: skip
    # The centre pixels look straight up at the camera.
    centre = np.argmin(np.hypot(fp.point[:, 0], fp.point[:, 2]))
    assert fp.wo[centre, 2] > 1.0 - 1e-3


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 75.0])
def test02_oblique_footprint_area_grows_as_one_over_cos(theta_deg: float) -> None:
    """The on-axis pixel (odd N) at distance D: area ((D - near) delta)^2 / cos(theta) to
    first order in the pixel's angle delta (here 5e-4 rad: the finite ray differential's
    second order is within the tolerance; ``near``: Mitsuba's rays start on the near plane)."""
    dist, fov, n = 2.0, 30.0, 1001
    t = math.radians(theta_deg)
    origin = (0.0, dist * math.cos(t), dist * math.sin(t))
    design = _design((origin, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0) if t else (0.0, 0.0, -1.0), fov),
                     (n, n))  # fmt: skip
    fp = sq.pixel_footprints(design)
    on_axis = np.flatnonzero((fp.pixel[:, 0] == n // 2) & (fp.pixel[:, 1] == n // 2))
    assert on_axis.size == 1
    k = int(on_axis[0])
    np.testing.assert_allclose(fp.point[k], 0.0, atol=1e-9)
    delta = 2.0 * math.tan(math.radians(fov) / 2.0) / n
    area_world = fp.size_uv[k] ** 2 * (2.0 * 1.5) ** 2
    want = ((dist - sq.NEAR_CLIP) * delta) ** 2 / math.cos(t)
    # Not round-off (float64, 1e-13 here): the residual is the difference's second order,
    # -delta tan(theta), 1.998e-3 at 75 degrees (measured 1.994e-3), the same on any machine.
    np.testing.assert_allclose(area_world, want, rtol=2e-3)
    np.testing.assert_allclose(fp.wo[k, 2], math.cos(t), rtol=1e-9)


def test03_footprints_match_mitsubas_ray_differentials(mi: types.ModuleType) -> None:
    """``cloth_plane`` as the renderer builds it: pixel-centre rays with one-pixel
    differentials (as ``fabric_path`` traces them) and ``compute_uv_partials``."""
    import drjit as dr

    from evaluators.render.scenes import SceneSetup, build_scene

    w, h = 48, 32  # not square: the fov is along the smaller side
    setup = SceneSetup(resolution=(w, h), spp=1, max_depth=2)
    scene = mi.load_dict(build_scene("cloth_plane", mi, {"type": "diffuse"}, setup))
    sensor = scene.sensors()[0]
    design = _cloth((w, h))
    fp = sq.pixel_footprints(design)
    pick = np.linspace(0, len(fp) - 1, 40).astype(int)
    px = fp.pixel[pick].astype(np.float64)
    centre = mi.Vector2f((px[:, 0] + 0.5) / w, (px[:, 1] + 0.5) / h)
    ray, _ = sensor.sample_ray_differential(
        time=0.0, sample1=0.0, sample2=centre, sample3=mi.Vector2f(0.5)
    )
    si = scene.ray_intersect(ray)
    si.compute_uv_partials(ray)
    assert bool(dr.all(si.is_valid()))
    uv = np.stack([np.asarray(si.uv.x), np.asarray(si.uv.y)], axis=1)
    # u along +x, v along -z over the square of half side 1.5 (Mitsuba's own uv).
    ours_uv = np.stack([(fp.point[pick, 0] + 1.5) / 3.0, (1.5 - fp.point[pick, 2]) / 3.0], axis=1)
    np.testing.assert_allclose(uv, ours_uv, atol=2e-5)
    got = np.stack(
        [
            np.stack([np.asarray(si.duv_dx.x), np.asarray(si.duv_dx.y)], axis=1),
            np.stack([np.asarray(si.duv_dy.x), np.asarray(si.duv_dy.y)], axis=1),
        ],
        axis=1,
    )
    np.testing.assert_allclose(got, fp.duv[pick], rtol=2e-4, atol=2e-6)
    # The shading frame's view (si.wi, local) is the query's wo.
    wi = np.stack([np.asarray(si.wi.x), np.asarray(si.wi.y), np.asarray(si.wi.z)], axis=1)
    np.testing.assert_allclose(wi, fp.wo[pick], atol=1e-5)
    # And the pixels that miss the square are the ones our table leaves out.
    every = mi.Vector2f(
        (np.tile(np.arange(w), h) + 0.5) / w, (np.repeat(np.arange(h), w) + 0.5) / h
    )
    all_rays, _ = sensor.sample_ray_differential(0.0, 0.0, every, mi.Vector2f(0.5))
    assert int(np.count_nonzero(np.asarray(scene.ray_intersect(all_rays).is_valid()))) == len(fp)


def _project(design: sq.SceneDesign, p: np.ndarray) -> np.ndarray:
    """Film coordinates in pixels of world points (the inverse of the pinhole map)."""
    origin, target, up = (np.asarray(v, dtype=np.float64) for v in design.camera[:3])
    fov = design.camera[3]
    forward = (target - origin) / np.linalg.norm(target - origin)
    left = np.cross(up, forward) / np.linalg.norm(np.cross(up, forward))
    new_up = np.cross(forward, left)
    v = p - origin
    x, y, z = v @ left, v @ new_up, v @ forward
    w, h = design.resolution
    tan_y = math.tan(math.radians(fov) / 2.0) * (1.0 if w >= h else h / w)
    tan_x = tan_y * w / h
    sx = 0.5 * (1.0 - x / z / tan_x)
    sy = 0.5 * (1.0 - y / z / tan_y)
    return np.stack([sx * w, sy * h], axis=1)


def test04_views_come_from_pixel_centres_and_sizes_from_their_footprints() -> None:
    design = _cloth((80, 60))
    q = sq.scene_queries(design, seed=3, first=0, count=3000)
    origin = np.asarray(design.camera[0], dtype=np.float64)
    world_wo = np.stack([q.wo[:, 0], q.wo[:, 2], -q.wo[:, 1]], axis=1)  # frame (+x, -z, +y)
    t = origin[1] / world_wo[:, 1]
    p = origin - t[:, None] * world_wo
    assert np.all(np.abs(p[:, [0, 2]]) <= 1.5 + 1e-9)
    film = _project(design, p)
    np.testing.assert_allclose(film - np.floor(film), 0.5, atol=1e-6)
    # The size is that pixel's footprint, by pixel lookup, in tiles.
    fp = sq.pixel_footprints(design)
    table = {tuple(px): s for px, s in zip(fp.pixel.tolist(), fp.size_uv, strict=True)}
    px = np.floor(film).astype(int)
    want = np.array([table[(int(a), int(b))] for a, b in px]) * design.tiles_per_uv
    np.testing.assert_allclose(q.size, want, rtol=1e-9)
    assert np.all(q.wo[:, 2] > 0.0) and np.all(q.centre >= 0.0) and np.all(q.centre < 1.0)
    np.testing.assert_allclose(np.linalg.norm(q.wi, axis=1), 1.0, rtol=1e-12)
    # A pattern whose tile is twice as high as wide: the area halves, the size by sqrt 2.
    q2 = sq.scene_queries(design, seed=3, first=0, count=3000, tile_aspect=0.5)
    np.testing.assert_allclose(q2.size, q.size * math.sqrt(0.5), rtol=1e-12)


def test05_a_complete_round_visits_every_pixel_once() -> None:
    design = _cloth((32, 32))
    fp = sq.pixel_footprints(design)
    q = sq.scene_queries(design, seed=1, first=len(fp), count=len(fp))  # round 1
    np.testing.assert_allclose(np.sort(q.size), np.sort(fp.size_uv * 16.0), rtol=1e-12)


def test06_light_shares_follow_the_irradiance() -> None:
    """BTDF pairs: the ground's share of the studio map's ``Y |cos| dOmega`` (quadrature
    at 1024 x 512, twice the sampler's texels); point-light pairs: the light's share."""
    design = _cloth((64, 64))
    n = 16384
    q = sq.scene_queries(design, seed=11, first=0, count=n)
    radiance = studio_envmap(1024, 512).astype(np.float64) @ sq.LUMA
    d = envmap_directions(1024, 512)
    sin = np.sin(np.pi * (np.arange(512) + 0.5) / 512)[:, None]
    weight = radiance * np.abs(d[..., 1]) * sin * (2 * np.pi / 1024) * (np.pi / 512)
    env_total, env_below = float(weight.sum()), float(weight[d[..., 1] < 0].sum())
    assert abs(env_total - sq.environment_irradiance()) < 0.01 * env_total
    # The point light at each query's point (recovered from wo as in test04).
    origin = np.asarray(design.camera[0], dtype=np.float64)
    world_wo = np.stack([q.wo[:, 0], q.wo[:, 2], -q.wo[:, 1]], axis=1)
    p = origin - (origin[1] / world_wo[:, 1])[:, None] * world_wo
    (pos, rgb) = design.lights[0]
    v = np.asarray(pos) - p
    r = np.linalg.norm(v, axis=1)
    e_light = float(np.asarray(rgb) @ sq.LUMA) * v[:, 1] / r**3
    share_light = e_light / (e_light + env_total)
    toward = v / r[:, None]
    is_light = np.linalg.norm(sq.to_local(toward) - q.wi, axis=1) < 1e-9
    sigma = math.sqrt(0.25 / n)
    assert abs(is_light.mean() - share_light.mean()) < 5 * sigma
    below = (q.wi[:, 2] < 0).mean()
    assert abs(below - (env_below / env_total * (1 - share_light)).mean()) < 5 * sigma
    assert 0.05 < below < 0.2 and 0.05 < is_light.mean() < 0.3  # cloth_plane's mix


def test07_deterministic_and_split_independent() -> None:
    design = _cloth((48, 48))
    a = sq.scene_queries(design, seed=5, first=0, count=5000)
    b = sq.scene_queries(design, seed=5, first=0, count=5000)
    parts = [sq.scene_queries(design, 5, lo, 1250) for lo in range(0, 5000, 1250)]
    for name in ("centre", "size", "wi", "wo"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(
            getattr(a, name), np.concatenate([getattr(p, name) for p in parts])
        )
    other = sq.scene_queries(design, seed=6, first=0, count=5000)
    assert not np.array_equal(a.wi, other.wi) and not np.array_equal(a.size, other.size)


def test08_scene_defs_match_the_built_scenes(mi: types.ModuleType) -> None:
    """``floor_half_size`` and ``environment_scale``, read by the generator, agree with
    what each builder puts in the scene."""
    from evaluators.render.scenes import SceneSetup, build_scene

    setup = SceneSetup(resolution=(8, 8), spp=1, max_depth=2)
    for name, d in SCENES.items():
        scene = build_scene(name, mi, {"type": "diffuse"}, setup)
        env = scene.get("environment")
        assert (env is not None) == (d.environment_scale > 0), name
        if env is not None:
            assert float(env.get("scale", 1.0)) == pytest.approx(d.environment_scale), name
        if d.floor_half_size is not None:
            (floor,) = [v for k, v in scene.items() if isinstance(v, dict) and "to_world" in v
                        and v.get("type") == "rectangle"]  # fmt: skip
            corner = floor["to_world"] @ mi.ScalarPoint3f(1.0, 1.0, 0.0)
            assert abs(corner[0]) == pytest.approx(d.floor_half_size), name
            assert abs(corner[2]) == pytest.approx(d.floor_half_size), name


def test09_bad_arguments() -> None:
    with pytest.raises(ValueError, match=">= 0"):
        sq.scene_queries(_cloth(), seed=0, first=-1, count=4)
    away = _design(((0.0, 2.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 1.0), 30.0))
    with pytest.raises(ValueError, match="no pixel"):
        sq.scene_queries(away, seed=0, first=0, count=4)
