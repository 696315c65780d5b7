"""The glint BSDF's tangent axes on every built-in scene, against a brute-force P-NDF.

The example's normals are written in (u, v, n): x along dp/du, y along dp/dv. Mitsuba's
shading frame need not follow them (its ``sphere`` has the frame's t axis opposite to
dp/dv), so the BSDF re-expresses the half vector in the uv tangent frame
(:func:`evaluators.render.bsdfs.glint.example_slopes`).

Reference (nothing here uses the lobes or the shading frame): at each hit of camera rays on
each scene, the half vector is built in world space from Mitsuba's dp/du and dp/dv
(Gram-Schmidt, in numpy), and the P-NDF is the brute-force density of the bilinear normal
field sampled over a Gaussian footprint at the hit's uv and blurred by sigma_r
(:func:`tests.helpers.glint_reference.bilinear_field`). The example has a strong mean tilt
towards +v, so a mirrored axis moves the whole P-NDF and fails by far.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from evaluators.render.bsdfs.glint import GlintLayer, example_slopes, layer_pndf
from evaluators.render.scenes import SCENES, SceneSetup, build_scene
from materials.glints.examples import procedural_example
from materials.glints.lobes import make_lobes
from materials.glints.pndf_drjit import Sym2, jit_lobes
from materials.microfacet import NAMED_CONDUCTORS
from tests.helpers.glint_reference import bilinear_field

SIDE = 16  # example texels, and global texels per uv: the example covers uv [0, 1) once
SIGMA_R = 0.03
FOOT = 2.0  # footprint standard deviation, texels
TILT = (0.06, 0.16)  # mean projected normal of the example, (s_x, s_y)


def _tilted_example() -> np.ndarray:
    n = procedural_example("scratches", SIDE, np.random.default_rng(4))
    s = n[..., :2] * 0.5 + np.array(TILT)
    z = np.sqrt(1.0 - np.sum(s * s, axis=-1, keepdims=True))
    return np.concatenate([s, z], axis=-1)


def _layer(mi: types.ModuleType, normals: np.ndarray) -> GlintLayer:
    eta, k = NAMED_CONDUCTORS["Al"]
    return GlintLayer(
        method="yan",
        lobes=jit_lobes(mi, make_lobes(normals, rate=4, sigma_r=SIGMA_R)),
        maps=None,
        transform=(np.eye(2), np.zeros(2)),
        texel_scale=1.0,
        fresnel=("conductor", eta, k),
        alpha=0.2,
        fallback_texels=FOOT,
    )


def _hits(mi: types.ModuleType, name: str) -> tuple[object, object, np.ndarray]:
    """The scene (kept alive while ``si`` is read), the surface interactions of a 12 x 12
    grid of camera rays, and which of them hit."""
    scene = mi.load_dict(build_scene(name, mi, {"type": "diffuse"}, SceneSetup((12, 12), 1, 2)))
    sensor = scene.sensors()[0]
    g = (np.arange(12) + 0.5) / 12
    fx, fy = np.meshgrid(g, g)
    pos = mi.Point2f(fx.ravel().astype(np.float32), fy.ravel().astype(np.float32))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    return scene, si, np.asarray(si.is_valid().numpy(), bool)


def _np(v: object) -> np.ndarray:
    return np.asarray(v, np.float64).reshape(3, -1).T if np.ndim(v) else np.asarray(v)


def _brute_pndf(normals: np.ndarray, c: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Mean over footprint samples u ~ N(c, FOOT^2 I) of N(q; s(u), sigma_r^2 I)."""
    u = c + FOOT * np.random.default_rng(0).standard_normal((20000, 2))
    s = bilinear_field(normals, np.mod(u, SIDE))
    d2 = np.sum((q[:, None, :] - s[None, :, :]) ** 2, axis=-1)
    return np.exp(-0.5 * d2 / SIGMA_R**2).mean(axis=1) / (2 * np.pi * SIGMA_R**2)


@pytest.mark.parametrize("name", sorted(SCENES))
def test01_pndf_axes_on_every_scene(mi: types.ModuleType, name: str) -> None:
    """D_P at world half vectors built from dp/du, dp/dv matches brute force (relative L1
    0.15: Monte Carlo over 20,000 footprint samples, and Yan's float32 lobes at rate 4;
    measured below 0.03 on every scene; the shading frame's own (h.x, h.y) gives about 1.0
    on the three sphere scenes)."""
    normals = _tilted_example()
    layer = _layer(mi, normals)
    scene, si, ok = _hits(mi, name)
    idx = np.flatnonzero(ok)[:: max(1, ok.sum() // 6)][:6]
    assert len(idx) >= 3, f"{name}: camera rays miss the object"
    n_all = _np(si.sh_frame.n.numpy())
    du_all, dv_all = _np(si.dp_du.numpy()), _np(si.dp_dv.numpy())
    uv_all = np.asarray(si.uv.numpy(), np.float64).reshape(2, -1).T
    rng = np.random.default_rng(1)
    for i in idx:
        n, du, dv = n_all[i], du_all[i], dv_all[i]
        eu = du - np.dot(du, n) * n
        eu /= np.linalg.norm(eu)
        ev = dv - np.dot(dv, n) * n - np.dot(dv, eu) * eu
        ev /= np.linalg.norm(ev)
        c = uv_all[i] * SIDE
        q = np.array(TILT) + rng.uniform(-0.25, 0.25, (300, 2))
        hz = np.sqrt(1.0 - np.sum(q * q, axis=1))
        h_world = q[:, :1] * eu + q[:, 1:] * ev + hz[:, None] * n
        m = len(q)
        si_at = _single(mi, si, i, m)
        h_local = si_at.to_local(mi.Vector3f(*h_world.T.astype(np.float32)))
        sx, sy = example_slopes(mi, si_at, h_local)
        fc = (mi.Float(np.full(m, c[0], np.float32)), mi.Float(np.full(m, c[1], np.float32)))
        f2 = mi.Float(np.full(m, FOOT * FOOT, np.float32))
        cov = Sym2(f2, mi.Float(np.zeros(m, np.float32)), f2)
        got = np.asarray(layer_pndf(mi, layer, fc, cov, (sx, sy), mi.Bool(True)).numpy())
        want = _brute_pndf(normals, c, q)
        err = np.abs(got - want).sum() / want.sum()
        assert err < 0.15, f"{name}, hit {i}: relative L1 {err:.3f}"
    del scene


def _single(mi: types.ModuleType, si: object, i: int, m: int) -> object:
    """The interaction ``si[i]`` repeated ``m`` times (frame and partials only)."""
    import drjit as dr

    out = dr.zeros(mi.SurfaceInteraction3f, m)
    pick = mi.UInt32(np.full(m, i, np.uint32))
    out.sh_frame = dr.gather(mi.Frame3f, si.sh_frame, pick)
    out.dp_du = dr.gather(mi.Vector3f, si.dp_du, pick)
    out.dp_dv = dr.gather(mi.Vector3f, si.dp_dv, pick)
    return out
