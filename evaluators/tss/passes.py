"""The three Dr.Jit passes of texture-space shading (Xu et al. 2025, Sec. 4.2) on a plane.

Scene: the textured square ``[-S/2, S/2]^2`` at z = 0 (S = :data:`PLANE_SIDE`), normal +z;
its object coordinates ``(u, v) = (x / S + 1/2, y / S + 1/2)`` in ``[0, 1]^2``, the model's
texture repeated ``uv_scale`` times per side (material coordinates ``uv * uv_scale``). The
surface's local frame is the world's (x = u axis, y = v axis, z = normal), so directions
need no rotation. Point lights: ``L = BTF(uv, wi, wo) * I / r^2`` (the BTF includes the
foreshortening), zero where the light or the eye is below the plane.

- :meth:`Plane.shade`: the shading pass, into an ``R x R`` radiance texture over the whole
  plane (row-major, texel ``[j, i]`` centred at ``uv = ((i + 1/2) / R, (j + 1/2) / R)``),
  for one eye position (``wo`` per texel) and every light (``wi``, ``r^2`` per texel). Two
  forms: per texel (:meth:`FusedBtf.eval` at each texel centre, the neural textures
  bilinear), or -- when the texture is texel-matched, ``R = model resolution x uv_scale``
  -- the paper's pass, :meth:`FusedBtf.shade_texture` once per repeat of the patch: the
  student's coarse MLP once per 2 x 2 block at the block centre's directions (Sec. 4.1).
- :meth:`Plane.lookup`: a frame from a radiance texture: each pixel's ray meets the plane,
  the texture is read there (bilinear between texel centres, clamped at the plane's edges);
  pixels that miss the plane are black.
- :meth:`Plane.reference`: screen-space shading of a frame: every pixel that meets the plane
  evaluated with :meth:`FusedBtf.eval` at its own uv, exact ``wo`` and ``wi`` (black
  elsewhere).

Cameras are passed as *opaque* Dr.Jit values, so a pass compiles once and its kernel is
reused frame after frame. Every pass returns three lazy ``Float`` channels (row-major).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluators.tss.params import PLANE_SIDE, PointLight
from models.btf.fused import BLOCK_TEXELS, FusedBtf


@dataclass(frozen=True)
class Camera:
    """A pinhole camera as opaque Dr.Jit scalars: ``eye``, ``right``, ``up``, ``forward``
    (3 ``Float`` each, world) and ``tan_half`` (``tan(fov_x / 2)``)."""

    eye: tuple[Any, Any, Any]
    right: tuple[Any, Any, Any]
    up: tuple[Any, Any, Any]
    forward: tuple[Any, Any, Any]
    tan_half: Any


class Plane:
    """The textured plane of ``fused`` under ``lights``, ``uv_scale`` repeats per side."""

    def __init__(self, fused: FusedBtf | Any, lights: Sequence[PointLight], uv_scale: int) -> None:
        self.fused = fused
        self.mi, self.dr = fused.mi, fused.dr
        self.lights = [(tuple(float(c) for c in li.position), li.rgb()) for li in lights]
        self.uv_scale = int(uv_scale)
        self.side = PLANE_SIDE

    def camera(self, eye: np.ndarray, basis: np.ndarray, tan_half: float) -> Camera:
        """Opaque Dr.Jit copies of one camera (``eye (3,)``, ``basis (3, 3)`` rows right, up,
        forward)."""
        dr, mi = self.dr, self.mi

        def vec(a: np.ndarray) -> tuple[Any, Any, Any]:
            return (dr.opaque(mi.Float, float(a[0])), dr.opaque(mi.Float, float(a[1])),
                    dr.opaque(mi.Float, float(a[2])))  # fmt: skip

        return Camera(vec(eye), vec(basis[0]), vec(basis[1]), vec(basis[2]),
                      dr.opaque(mi.Float, float(tan_half)))  # fmt: skip

    def amortises(self, resolution: int, everywhere: bool) -> bool:
        """Whether the amortised pass runs at ``resolution``: texel-matched, or (with
        ``everywhere``) any even resolution for the student, through
        :meth:`FusedStudent.eval_block <models.btf.fused.FusedStudent.eval_block>`."""
        if self.texel_matched(resolution):
            return True
        f = self.fused
        return (
            everywhere
            and getattr(f, "amortisable", True)
            and getattr(f, "kind", None) == "c2f"
            and resolution % 2 == 0
        )

    def texel_matched(self, resolution: int) -> bool:
        """Whether an ``R x R`` radiance texture puts one texel on each neural texel."""
        f = self.fused
        if not getattr(f, "amortisable", True):  # a user's model: no 2 x 2 pass
            return False
        return f.h == f.w and resolution == f.h * self.uv_scale

    # -- geometry ------------------------------------------------------------------------
    def _toward(self, px: Any, py: Any, q: Sequence[Any]) -> tuple[list[Any], Any]:
        """The unit direction from plane points ``(px, py, 0)`` to ``q`` and the squared
        distance."""
        dx, dy, dz = q[0] - px, q[1] - py, q[2]
        r2 = dx * dx + dy * dy + dz * dz
        inv = self.dr.rsqrt(r2)
        return [dx * inv, dy * inv, dz * inv], r2

    def _point(self, u: Any, v: Any) -> tuple[Any, Any]:
        return (u - 0.5) * self.side, (v - 0.5) * self.side

    def _weights(self, px: Any, py: Any, wo_z: Any) -> list[tuple[list[Any], list[Any]]]:
        """Per light: ``wi`` at the points and the factors ``I_c / r^2`` (0 below the
        horizon of the light or the eye)."""
        dr = self.dr
        out = []
        for pos, rgb in self.lights:
            wi, r2 = self._toward(px, py, pos)
            w = dr.select((wi[2] > 0.0) & (wo_z > 0.0), 1.0 / r2, 0.0)
            out.append((wi, [w * c for c in rgb]))
        return out

    def _shade_points(self, u: Any, v: Any, cam: Camera) -> list[Any]:
        """Radiance at object coordinates ``(u, v)`` seen from ``cam.eye``, by
        :meth:`FusedBtf.eval` (exact directions per point)."""
        mi, s = self.mi, self.uv_scale
        px, py = self._point(u, v)
        wo, _ = self._toward(px, py, cam.eye)
        uv, wo_v = mi.Point2f(u * s, v * s), mi.Vector3f(*wo)
        total = [mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)]
        for wi, factor in self._weights(px, py, wo[2]):
            f = self.fused.eval(uv, mi.Vector3f(*wi), wo_v)
            total = [self.dr.fma(f[c], factor[c], total[c]) for c in range(3)]
        return total

    def _pixels(self, cam: Camera, width: int, height: int) -> tuple[Any, Any, Any]:
        """``(hit, u, v)`` of each pixel's ray (row-major, row 0 at the top): where it meets
        the plane from above, object coordinates; elsewhere ``hit`` is false and ``(u, v)``
        the plane's centre (safe texture indices)."""
        dr, mi = self.dr, self.mi
        idx = dr.arange(mi.UInt32, width * height)
        x, y = mi.Float(idx % width), mi.Float(idx // width)
        nx = ((x + 0.5) * (2.0 / width) - 1.0) * cam.tan_half
        ny = (1.0 - (y + 0.5) * (2.0 / height)) * cam.tan_half * (height / width)
        d = [cam.right[k] * nx + cam.up[k] * ny + cam.forward[k] for k in range(3)]
        t = -cam.eye[2] / d[2]
        px, py = cam.eye[0] + t * d[0], cam.eye[1] + t * d[1]
        half = 0.5 * self.side
        hit = (d[2] < 0.0) & (dr.abs(px) <= half) & (dr.abs(py) <= half)
        u = dr.select(hit, px / self.side + 0.5, 0.5)
        v = dr.select(hit, py / self.side + 0.5, 0.5)
        return hit, u, v

    # -- the passes ----------------------------------------------------------------------
    def shade(
        self, resolution: int, cam: Camera, *, amortised: bool, everywhere: bool = False
    ) -> list[Any]:
        """The radiance texture, ``R x R`` row-major, for the eye of ``cam``. ``amortised``
        and texel-matched: :meth:`FusedBtf.shade_texture` per patch repeat; ``amortised``
        and ``everywhere`` at another even ``R`` (the student): the 2 x 2 blocks of the
        radiance texture (:meth:`_shade_any_blocks`); else per texel."""
        if amortised and self.texel_matched(resolution):
            return self._shade_blocks(cam)
        if amortised and self.amortises(resolution, everywhere):
            return self._shade_any_blocks(resolution, cam)
        dr, mi = self.dr, self.mi
        r = int(resolution)
        idx = dr.arange(mi.UInt32, r * r)
        u = (mi.Float(idx % r) + 0.5) / r
        v = (mi.Float(idx // r) + 0.5) / r
        return self._shade_points(u, v, cam)

    def _shade_blocks(self, cam: Camera) -> list[Any]:
        """The texel-matched pass through :meth:`FusedBtf.shade_texture`, once per light and
        patch repeat, scattered into the ``R x R`` texture. The network's directions are
        taken at each lane's centre (the student's lanes are 2 x 2 blocks: the corner their
        four texels share, Sec. 4.1); the light factors ``I / r^2`` are per texel."""
        dr, mi, f = self.dr, self.mi, self.fused
        n, s = f.h, self.uv_scale
        r = n * s
        c2f = f.kind == "c2f"
        side = n // 2 if c2f else n  # lanes per row
        lane = dr.arange(mi.UInt32, f.lanes())
        lj, li = lane // side, lane % side
        out = [dr.zeros(mi.Float, r * r) for _ in range(3)]
        for ty in range(s):
            for tx in range(s):
                if c2f:  # block (lj, li) spans texels 2 lj, 2 lj + 1: centre at 2 lj + 1
                    gu = mi.Float(tx * n + 2 * li + 1) / r
                    gv = mi.Float(ty * n + 2 * lj + 1) / r
                    texels = [(ty * n + 2 * lj + dy, tx * n + 2 * li + dx)
                              for dy, dx in BLOCK_TEXELS]  # fmt: skip
                else:
                    gu = (mi.Float(tx * n + li) + 0.5) / r
                    gv = (mi.Float(ty * n + lj) + 0.5) / r
                    texels = [(ty * n + lj, tx * n + li)]
                px, py = self._point(gu, gv)
                wo, _ = self._toward(px, py, cam.eye)
                wo_v = mi.Vector3f(*wo)
                factors = []  # per texel of the lane, per light: (I_c / r^2)
                for tj, ti in texels:
                    qx, qy = self._point((mi.Float(ti) + 0.5) / r, (mi.Float(tj) + 0.5) / r)
                    wo_t, _ = self._toward(qx, qy, cam.eye)
                    factors.append([w for _, w in self._weights(qx, qy, wo_t[2])])
                acc = [[mi.Float(0.0)] * 3 for _ in texels]
                for k, (pos, _) in enumerate(self.lights):
                    wi, _ = self._toward(px, py, pos)
                    outs = f.shade_texture(mi.Vector3f(*wi), wo_v)
                    for t, rgb in enumerate(outs):
                        w = factors[t][k]
                        acc[t] = [dr.fma(rgb[c], w[c], acc[t][c]) for c in range(3)]
                for (tj, ti), rgb in zip(texels, acc, strict=True):
                    index = mi.UInt32(tj) * r + mi.UInt32(ti)
                    for c in range(3):
                        dr.scatter(out[c], rgb[c], index)
        return out

    def _shade_any_blocks(self, resolution: int, cam: Camera) -> list[Any]:
        """The student's amortised pass at any even ``R``: one lane per 2 x 2 block of the
        radiance texture, the coarse MLP once at the block's centre (its directions, and the
        coarse texel holding it), the fine MLP at each of the four texel centres; the light
        factors ``I / r^2`` per texel (as :meth:`_shade_blocks`)."""
        dr, mi, s = self.dr, self.mi, self.uv_scale
        r = int(resolution)
        half = r // 2
        lane = dr.arange(mi.UInt32, half * half)
        bj, bi = lane // half, lane % half
        gu, gv = mi.Float(2 * bi + 1) / r, mi.Float(2 * bj + 1) / r
        px, py = self._point(gu, gv)
        wo, _ = self._toward(px, py, cam.eye)
        wo_v = mi.Vector3f(*wo)
        texels = [(2 * bj + dy, 2 * bi + dx) for dy, dx in BLOCK_TEXELS]
        uvs, factors = [], []
        for tj, ti in texels:
            tu, tv = (mi.Float(ti) + 0.5) / r, (mi.Float(tj) + 0.5) / r
            uvs.append(mi.Point2f(tu * s, tv * s))
            qx, qy = self._point(tu, tv)
            wo_t, _ = self._toward(qx, qy, cam.eye)
            factors.append([w for _, w in self._weights(qx, qy, wo_t[2])])
        acc = [[mi.Float(0.0)] * 3 for _ in texels]
        centre = mi.Point2f(gu * s, gv * s)
        for k, (pos, _) in enumerate(self.lights):
            wi, _ = self._toward(px, py, pos)
            student: Any = self.fused  # amortises(): a FusedStudent
            outs = student.eval_block(centre, uvs, mi.Vector3f(*wi), wo_v)
            for t, rgb in enumerate(outs):
                w = factors[t][k]
                acc[t] = [dr.fma(rgb[c], w[c], acc[t][c]) for c in range(3)]
        out = [dr.zeros(mi.Float, r * r) for _ in range(3)]
        for (tj, ti), rgb in zip(texels, acc, strict=True):
            index = mi.UInt32(tj) * r + mi.UInt32(ti)
            for c in range(3):
                dr.scatter(out[c], rgb[c], index)
        return out

    def lookup(self, texture: Sequence[Any], resolution: int, cam: Camera, size: tuple[int, int]
               ) -> list[Any]:  # fmt: skip
        """A frame of ``size = (W, H)`` pixels from the ``R x R`` radiance ``texture``: bilinear
        between texel centres, clamped at the edges; black off the plane."""
        dr, mi = self.dr, self.mi
        r = int(resolution)
        hit, u, v = self._pixels(cam, *size)
        x, y = u * r - 0.5, v * r - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0, j0 = mi.Int32(x0), mi.Int32(y0)
        i1 = dr.clip(i0 + 1, 0, r - 1)
        j1 = dr.clip(j0 + 1, 0, r - 1)
        i0, j0 = dr.clip(i0, 0, r - 1), dr.clip(j0, 0, r - 1)
        corners = [mi.UInt32(j * r + i) for j, i in ((j0, i0), (j0, i1), (j1, i0), (j1, i1))]
        weights = [(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]
        out = []
        for c in range(3):
            value = mi.Float(0.0)
            for idx, w in zip(corners, weights, strict=True):
                value = dr.fma(dr.gather(mi.Float, texture[c], idx), w, value)
            out.append(dr.select(hit, value, 0.0))
        return out

    def reference(self, cam: Camera, size: tuple[int, int]) -> list[Any]:
        """Screen-space shading of a frame of ``size = (W, H)`` pixels (black off the plane)."""
        hit, u, v = self._pixels(cam, *size)
        return [self.dr.select(hit, c, 0.0) for c in self._shade_points(u, v, cam)]

    # -- to numpy --------------------------------------------------------------------------
    @staticmethod
    def image(channels: Sequence[Any], width: int, height: int) -> np.ndarray:
        """``(H, W, 3)`` float32 of three evaluated row-major channels."""
        return np.stack([np.asarray(c, np.float32) for c in channels], axis=-1).reshape(
            height, width, 3
        )
