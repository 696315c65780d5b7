"""BTF slices path-traced with Mitsuba 3: one image per (light ``wi``, view ``wo``) pair.

The reference for every BTF in matforge. Each slice is what an orthographic camera along
``wo`` sees of the patch ``[-0.5, 0.5]^2`` (see :mod:`~evaluators.render.btf.patch`) lit by
a ``directional`` emitter from ``wi`` with irradiance 1 on a plane perpendicular to the
light (``E_perp = 1``), so the radiance *is* the BTF in UBO2014's convention,
``L_o / E_perp``, foreshortening included (a flat Lambertian plane gives ``albedo / pi *
cos(theta_i)``).

Texel ``[j, i]`` of an ``r x r`` slice is the mean radiance over its square of the mean
plane, ``[i / r, (i + 1) / r) x [j / r, (j + 1) / r)`` shifted by ``-0.5``: each of ``spp``
rays starts from a uniformly jittered point of that square moved up along ``wo`` and
travels along ``-wo``, so the first surface point it meets is the one the camera sees there
(parallax and masking included). Radiance comes from Mitsuba's own ``path`` integrator
(``integrator.sample``): next-event estimation of the delta light, shadow rays,
interreflection to ``max_depth``. Nothing of ours enters the light transport.

The rays' positions in a texel are stratified (a Latin hypercube) by default. The Monte
Carlo standard error of a texel is its sample standard deviation over ``sqrt(spp)`` (an
upper bound under stratification); a slice's is the root mean square of that over texels
and channels.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Rays traced per pass (bounds the Dr.Jit working set: ~0.5 GiB at 2^21).
RAYS_PER_PASS = 1 << 21
#: Distance of the ray origins from the mean plane, along ``wo`` (beyond any relief).
ORIGIN_DISTANCE = 10.0


@dataclass(frozen=True)
class Slice:
    """One rendered slice: ``rgb`` ``(r, r, 3)`` float32 (the BTF), ``stderr`` (RMS of the
    per-texel standard errors), ``texel_stderr`` ``(r, r, 3)`` float32."""

    rgb: np.ndarray
    stderr: float
    texel_stderr: np.ndarray


def _pass_seed(seed: int, index: int) -> int:
    return int((seed * 1_000_003 + index * 7_919 + 1) % (2**31 - 1))


class SliceRenderer:
    """Renders slices of one surface shape (a ``flat_shape`` dict or a ``procedural_mesh``).

    The scene is built once; :meth:`render` turns the directional light with
    ``mi.traverse`` (its ``to_world``) instead of rebuilding the mesh for every light.
    """

    def __init__(
        self,
        mi: types.ModuleType,
        shape: Any,
        *,
        max_depth: int,
        rays_per_pass: int = RAYS_PER_PASS,
    ) -> None:
        self.mi = mi
        self.max_depth = max_depth
        self.rays_per_pass = max(1, int(rays_per_pass))
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": {"type": "path", "max_depth": int(max_depth)},
                "patch": shape,
                "sun": {
                    "type": "directional",
                    "direction": [0.0, 0.0, -1.0],
                    "irradiance": {"type": "rgb", "value": 1.0},
                },
            }
        )
        self._params = mi.traverse(self.scene)
        self._light: tuple[float, ...] | None = None

    def _set_light(self, wi: np.ndarray) -> None:
        key = tuple(float(v) for v in wi)
        if key == self._light:
            return
        target = (-np.asarray(wi, np.float64)).tolist()
        up = [0.0, 1.0, 0.0] if abs(float(wi[1])) < 0.9 else [1.0, 0.0, 0.0]
        self._params["sun.to_world"] = self.mi.Transform4f().look_at(
            origin=[0.0, 0.0, 0.0], target=target, up=up
        )
        self._params.update()
        self._light = key

    def render(
        self,
        wi: np.ndarray,
        wo: np.ndarray,
        resolution: int,
        spp: int,
        seed: int,
        *,
        stratified: bool = True,
    ) -> Slice:
        """The slice for light ``wi`` and view ``wo`` (unit vectors, z > 0) at
        ``resolution^2`` texels and ``spp`` rays per texel (``spp >= 2`` for an error
        estimate), deterministic in ``seed``.

        ``stratified``: the rays' positions in a texel form a Latin hypercube (one per row
        and per column of an ``spp x spp`` grid, the column order shuffled per texel), which
        takes most of the texel's own variation out of the error; the reported standard
        error then overestimates the true one (it treats the samples as independent).
        Otherwise they are independent and uniform, and the error falls as ``1/sqrt(spp)``.
        """
        import drjit as dr

        mi = self.mi
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        if wi[2] <= 0.0 or wo[2] <= 0.0:
            raise ValueError("light and view must lie above the surface (z > 0)")
        self._set_light(wi)
        res, spp = int(resolution), int(spp)
        rows_per_pass = max(1, self.rays_per_pass // (res * spp))
        mean = np.zeros((res, res, 3), np.float64)
        sq_dev = np.zeros((res, res, 3), np.float64)
        integrator = self.scene.integrator()
        for p, r0 in enumerate(range(0, res, rows_per_pass)):
            r1 = min(res, r0 + rows_per_pass)
            n = (r1 - r0) * res * spp
            texel = np.arange(n) // spp
            ty = r0 + texel // res
            tx = texel % res
            rng = np.random.default_rng([seed, p])
            if stratified:
                rows = np.tile(np.arange(spp, dtype=np.float64), n // spp)
                cols = rng.permuted(np.arange(spp, dtype=np.float64)[None, :].repeat(
                    n // spp, axis=0), axis=1).ravel()  # fmt: skip
                x = (tx + (rows + rng.random(n)) / spp) / res - 0.5
                y = (ty + (cols + rng.random(n)) / spp) / res - 0.5
            else:
                x = (tx + rng.random(n)) / res - 0.5
                y = (ty + rng.random(n)) / res - 0.5
            org = np.stack(
                [x + wo[0] * ORIGIN_DISTANCE, y + wo[1] * ORIGIN_DISTANCE,
                 np.full(n, wo[2] * ORIGIN_DISTANCE)], axis=0,
            ).astype(np.float32)  # fmt: skip
            d = np.repeat((-wo).astype(np.float32)[:, None], n, axis=1)
            ray = mi.Ray3f(mi.Point3f(*org), mi.Vector3f(*d))
            sampler = mi.load_dict({"type": "independent"})
            sampler.seed(_pass_seed(seed, p), n)
            radiance, _, _ = integrator.sample(self.scene, sampler, ray)
            # Per-texel mean and squared deviations (two passes: no float32 cancellation)
            # of adjacent lanes inside Dr.Jit; only two values per texel and channel come
            # back to the host.
            dr.eval(radiance)
            texel_mean = dr.block_sum(radiance, spp) / spp
            lane_texel = dr.arange(mi.UInt32, n) // spp
            dev = radiance - dr.gather(mi.Color3f, texel_mean, lane_texel)
            ssq = dr.block_sum(dev * dev, spp)
            dr.eval(texel_mean, ssq)
            shape = (r1 - r0, res, 3)
            mean[r0:r1] = np.asarray(texel_mean, dtype=np.float32).T.reshape(shape)
            sq_dev[r0:r1] = np.asarray(ssq, dtype=np.float32).T.reshape(shape)
        if spp > 1:
            texel_se = np.sqrt(sq_dev / (spp - 1) / spp)
        else:
            texel_se = np.full_like(mean, np.nan)
        stderr = float(np.sqrt(np.mean(np.square(texel_se))))
        return Slice(
            rgb=mean.astype(np.float32),
            stderr=stderr if math.isfinite(stderr) else float("nan"),
            texel_stderr=texel_se.astype(np.float32),
        )
