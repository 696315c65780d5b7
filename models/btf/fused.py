"""BTF models in Dr.Jit: the MLPs fused into the kernel (:mod:`models.fused_mlp`), the neural
textures as Dr.Jit arrays, one model evaluation per SIMD lane.

Two entry points:

- :meth:`FusedBtf.shade_texture`: every texel of the texture for given directions, the
  texture-space shading pass of Sec. 4.2. For the student, one lane per 2 x 2 block: the
  coarse MLP runs once (directions at the block's centre, Sec. 4.1) and the fine MLP four
  times, so ``M_c`` is amortised over four texels. NeuMIP and Lafortune run one lane per
  texel. Texels are read at their centres (no filtering: the radiance texture and the
  neural textures share a resolution), lane by lane, without gathers.
- :meth:`FusedBtf.eval`: one evaluation at arbitrary texture coordinates (a Mitsuba BSDF's
  ``eval``): the neural textures bilinear and periodic (NeuMIP, the student's fine
  texture), the student's coarse texture at the centre of the 2 x 2 block holding ``uv``,
  Lafortune's parameters from the nearest texel.

One class per model: :class:`FusedNeumip`, :class:`FusedStudent` (the coarse-to-fine
student, ``c2f``) and :class:`FusedLafortune`, each holding its own textures and kernels;
:class:`FusedBtf` is their shared base, and ``FusedBtf(model, mi)`` makes the class of
``model.kind`` (:data:`FUSED_MODELS`).

The reference is :class:`models.btf.portable.PortableBtf` (numpy), matched to float32
precision; ``tests/unit/models/btf/test_btf_networks.py`` checks it.
"""

from __future__ import annotations

import types
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from materials.btf.lafortune import LOBE_PARAMS, LOBES, M_OFFSET, N_OFFSET, RHO_S_OFFSET
from models.btf.portable import PortableBtf
from models.fused_mlp import fused_mlp

#: The texels of a 2 x 2 block, ``(dy, dx)``, in the order of the student's outputs.
BLOCK_TEXELS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (1, 0), (1, 1))


@dataclass
class _Texture:
    """A ``(C, H, W)`` texture as ``C`` flat Dr.Jit arrays (row-major texels)."""

    channels: list[Any]
    h: int
    w: int


def _float16_type(mi: types.ModuleType) -> Any:
    """Dr.Jit's half-precision array of Mitsuba's variant (``mi.Float16``: LLVM or CUDA)."""
    return mi.Float16


class FusedBtf:
    """A portable BTF model ready to be traced into Dr.Jit kernels: the base of one class
    per model. ``FusedBtf(model, mi)`` makes the subclass of ``model.kind``
    (:data:`FUSED_MODELS`); ``ValueError`` for a model without one."""

    #: The :attr:`PortableBtf.kind <models.btf.portable.PortableBtf.kind>` a subclass fuses.
    model_kind: ClassVar[str] = ""

    def __new__(cls, model: PortableBtf, mi: types.ModuleType, *, half: bool = False) -> FusedBtf:
        if cls is FusedBtf:
            found = FUSED_MODELS.get(model.kind)
            if found is None:
                raise ValueError(
                    f"no fused BTF model {model.kind!r}; fused: {', '.join(FUSED_MODELS)}"
                )
            cls = found
        return super().__new__(cls)

    def __init__(self, model: PortableBtf, mi: types.ModuleType, *, half: bool = False) -> None:
        """``half``: keep the textures (neural features, Lafortune parameters) in float16
        and widen them to float32 in the kernel. This is half-precision *storage* only: the
        MLPs' arithmetic stays float32 (the paper's inference computes in half precision
        too; Dr.Jit's LLVM backend has ``Float16`` arrays but no half-precision fused MLP
        here, so that part is not modelled). What it buys on this CPU is memory traffic:
        half the bytes per texture fetch."""
        import drjit as dr

        self.model = model
        self.mi = mi
        self.dr = dr
        self.kind = model.kind
        self.h, self.w = model.resolution
        self.half = half
        self._store = _float16_type(mi) if half else mi.Float
        self._np_type = np.float16 if half else np.float32
        self._load(model)

    def _load(self, model: PortableBtf) -> None:
        """Hold the model's textures and layers as Dr.Jit arrays."""
        raise NotImplementedError

    # -- building blocks -----------------------------------------------------------------
    def _arr1(self, a: np.ndarray) -> Any:
        return self._store(np.ascontiguousarray(a, dtype=self._np_type).reshape(-1))

    def _tex(self, arr: np.ndarray) -> _Texture:
        c, h, w = arr.shape
        flat = np.asarray(arr).reshape(c, h * w)
        return _Texture([self._arr1(flat[k]) for k in range(c)], h, w)

    def _gather(self, tex: _Texture, index: Any) -> list[Any]:
        return [self.mi.Float(self.dr.gather(type(c), c, index)) for c in tex.channels]

    def _wide(self, channels: list[Any]) -> list[Any]:
        return [self.mi.Float(c) for c in channels] if self.half else list(channels)

    def _bilinear(self, tex: _Texture, u: Any, v: Any) -> list[Any]:
        dr, mi = self.dr, self.mi
        x = u * tex.w - 0.5
        y = v * tex.h - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0 = mi.Int32(x0)
        j0 = mi.Int32(y0)
        i0 = i0 - tex.w * mi.Int32(dr.floor(mi.Float(i0) / tex.w))
        j0 = j0 - tex.h * mi.Int32(dr.floor(mi.Float(j0) / tex.h))
        i1 = dr.select(i0 + 1 >= tex.w, 0, i0 + 1)
        j1 = dr.select(j0 + 1 >= tex.h, 0, j0 + 1)
        idx = [mi.UInt32(j * tex.w + i) for j, i in ((j0, i0), (j0, i1), (j1, i0), (j1, i1))]
        a, b, c, d = (self._gather(tex, k) for k in idx)
        w00, w01 = (1 - fx) * (1 - fy), fx * (1 - fy)
        w10, w11 = (1 - fx) * fy, fx * fy
        return [
            dr.fma(a_, w00, dr.fma(b_, w01, dr.fma(c_, w10, d_ * w11)))
            for a_, b_, c_, d_ in zip(a, b, c, d, strict=True)
        ]

    def _out(self, rgb: list[Any]) -> Any:
        dr = self.dr
        return self.mi.Color3f(*(dr.maximum(c, 0.0) for c in rgb))

    # -- evaluation at arbitrary uv --------------------------------------------------------
    def eval(self, uv: Any, wi: Any, wo: Any) -> Any:
        """The BTF (foreshortening included) at texture coordinates ``uv`` (``Point2f``,
        periodic) for light ``wi`` and view ``wo`` (``Vector3f``, local frame, z up):
        ``Color3f``, lazy."""
        dr = self.dr
        u = uv[0] - dr.floor(uv[0])
        v = uv[1] - dr.floor(uv[1])
        return self._eval(u, v, [wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]])

    def _eval(self, u: Any, v: Any, wi: list[Any], wo: list[Any]) -> Any:
        """:meth:`eval` at ``u, v`` in [0, 1), directions as component lists."""
        raise NotImplementedError

    # -- the texture-space shading pass ----------------------------------------------------
    def shade_texture(self, wi: Any, wo: Any) -> list[Any]:
        """Every texel at its centre, one lane per texel (NeuMIP, Lafortune) or per 2 x 2
        block (the student), with the lanes' directions ``wi``, ``wo`` (``Vector3f``;
        :meth:`lanes` lanes: row-major texels, or row-major blocks for the student, whose
        directions are taken at the block centre, Sec. 4.1). The textures are read
        lane by lane (contiguous loads: lane ``k`` is texel / block ``k``). Returns a list of
        ``Color3f``: ``[all texels]`` for NeuMIP and Lafortune; for the student the four
        block-lane colours of the texels ``(2j + dy, 2i + dx)`` in :data:`BLOCK_TEXELS`
        order. :meth:`assemble` makes an image of either."""
        return self._shade([wi[0], wi[1], wi[2]], [wo[0], wo[1], wo[2]])

    def _shade(self, wi: list[Any], wo: list[Any]) -> list[Any]:
        """:meth:`shade_texture` with directions as component lists."""
        raise NotImplementedError

    def _lane_grid(self) -> tuple[int, int]:
        """``(rows, columns)`` of the lanes of :meth:`shade_texture`: the texels."""
        return self.h, self.w

    def lanes(self) -> int:
        """Lanes of :meth:`shade_texture`: texels, or 2 x 2 blocks for the student."""
        h, w = self._lane_grid()
        return h * w

    def lane_centres(self) -> np.ndarray:
        """``(lanes, 2)`` uv of each lane's texel centre, or block centre for the student."""
        h, w = self._lane_grid()
        jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        return np.stack([(ii.ravel() + 0.5) / w, (jj.ravel() + 0.5) / h], axis=1)

    def assemble(self, outs: list[Any]) -> np.ndarray:
        """The ``(H, W, 3)`` float32 image of :meth:`shade_texture`'s result."""
        if len(outs) == 1:
            return np.asarray(outs[0], np.float32).T.reshape(self.h, self.w, 3)
        hb, wb = self.h // 2, self.w // 2
        img = np.empty((self.h, self.w, 3), np.float32)
        for (dy, dx), c in zip(BLOCK_TEXELS, outs, strict=True):
            img[dy::2, dx::2] = np.asarray(c, np.float32).T.reshape(hb, wb, 3)
        return img

    def slice(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """One BTF slice (constant directions) through the texture-space pass, ``(H, W, 3)``."""
        mi = self.mi
        n = self.lanes()
        wi_v = mi.Vector3f(*(mi.Float(np.full(n, float(c), np.float32)) for c in wi))
        wo_v = mi.Vector3f(*(mi.Float(np.full(n, float(c), np.float32)) for c in wo))
        return self.assemble(self.shade_texture(wi_v, wo_v))


class FusedNeumip(FusedBtf):
    """The modified NeuMIP: a neural texture, bilinear and periodic at arbitrary uv, and one
    MLP of the features and the directions' ``xy``."""

    model_kind = "neumip"

    def _load(self, model: PortableBtf) -> None:
        self.texture = self._tex(model.textures["texture"])
        names = sorted(k for k in model.layers if k.startswith("hidden")) + ["out"]
        self.mlp = [model.layers[k] for k in names]

    def _eval(self, u: Any, v: Any, wi: list[Any], wo: list[Any]) -> Any:
        feats = self._bilinear(self.texture, u, v)
        return self._out(fused_mlp(self.mlp, [*feats, wi[0], wi[1], wo[0], wo[1]]))

    def _shade(self, wi: list[Any], wo: list[Any]) -> list[Any]:
        feats = self._wide(self.texture.channels)
        return [self._out(fused_mlp(self.mlp, [*feats, wi[0], wi[1], wo[0], wo[1]]))]


class FusedStudent(FusedBtf):
    """The coarse-to-fine student (Sec. 4.1): a coarse texture, one texel per 2 x 2 block,
    through the coarse MLP with the directions and their half vector, then the fine MLP of
    its output and the fine texture."""

    model_kind = "c2f"

    def _load(self, model: PortableBtf) -> None:
        t = model.textures
        self.coarse_tex = self._tex(t["coarse_texture"])
        self.fine_tex = self._tex(t["fine_texture"])
        # The texture-space pass reads the fine texture block by block: four planes of
        # (H/2, W/2) texels, one per position (dy, dx) in the block, so lane b of the
        # pass reads element b of each plane (a contiguous load, no gather).
        ft = np.asarray(t["fine_texture"], np.float32)
        self.fine_planes = [
            [self._arr1(ft[c, dy::2, dx::2]) for c in range(ft.shape[0])] for dy, dx in BLOCK_TEXELS
        ]
        self.coarse = [model.layers["coarse1"], model.layers["coarse2"]]
        self.fine = [model.layers["fine1"], model.layers["fine2"]]

    @staticmethod
    def _half(dr: Any, wi: list[Any], wo: list[Any]) -> list[Any]:
        hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
        inv = dr.rsqrt(dr.maximum(hx * hx + hy * hy + hz * hz, 1e-16))
        return [hx * inv, hy * inv, hz * inv]

    def _coarse_z(self, feats: list[Any], wi: list[Any], wo: list[Any]) -> list[Any]:
        return fused_mlp(self.coarse, [*feats, *wi, *wo, *self._half(self.dr, wi, wo)])

    def _eval(self, u: Any, v: Any, wi: list[Any], wo: list[Any]) -> Any:
        dr, mi = self.dr, self.mi
        ct = self.coarse_tex
        bi = dr.minimum(mi.UInt32(u * ct.w), ct.w - 1)
        bj = dr.minimum(mi.UInt32(v * ct.h), ct.h - 1)
        z = self._coarse_z(self._gather(ct, bj * ct.w + bi), wi, wo)
        fine = self._bilinear(self.fine_tex, u, v)
        return self._out(fused_mlp(self.fine, [*z, *fine]))

    def eval_block(self, centre: Any, texels: list[Any], wi: Any, wo: Any) -> list[Any]:
        """The 2 x 2 amortisation at arbitrary texture coordinates (a radiance texture of any
        resolution): ``z_c`` once, from the coarse texel holding ``centre`` (``Point2f``,
        periodic) with the directions ``wi``, ``wo`` (``Vector3f``, taken at the centre), and
        the fine MLP at each of ``texels`` (``Point2f`` each, fine texture bilinear), as
        :meth:`eval` would evaluate them but for the shared ``z_c``. Returns one ``Color3f``
        per texel."""
        dr, mi = self.dr, self.mi
        ct = self.coarse_tex
        u = centre[0] - dr.floor(centre[0])
        v = centre[1] - dr.floor(centre[1])
        bi = dr.minimum(mi.UInt32(u * ct.w), ct.w - 1)
        bj = dr.minimum(mi.UInt32(v * ct.h), ct.h - 1)
        z = self._coarse_z(self._gather(ct, bj * ct.w + bi), [wi[0], wi[1], wi[2]],
                           [wo[0], wo[1], wo[2]])  # fmt: skip
        out = []
        for t in texels:
            tu, tv = t[0] - dr.floor(t[0]), t[1] - dr.floor(t[1])
            out.append(
                self._out(fused_mlp(self.fine, [*z, *self._bilinear(self.fine_tex, tu, tv)]))
            )
        return out

    def _shade(self, wi: list[Any], wo: list[Any]) -> list[Any]:
        z = self._coarse_z(self._wide(self.coarse_tex.channels), wi, wo)
        return [
            self._out(fused_mlp(self.fine, [*z, *self._wide(plane)])) for plane in self.fine_planes
        ]

    def _lane_grid(self) -> tuple[int, int]:
        """One lane per 2 x 2 block."""
        return self.h // 2, self.w // 2


class FusedLafortune(FusedBtf):
    """The 4-lobe Lafortune baseline: its parameters per texel, from the nearest texel at
    arbitrary uv."""

    model_kind = "lafortune"

    def _load(self, model: PortableBtf) -> None:
        p = np.asarray(model.textures["params"], np.float32)  # (H, W, 55)
        self.params = self._tex(np.moveaxis(p, -1, 0))

    def _lafortune(self, p: list[Any], wi: list[Any], wo: list[Any]) -> Any:
        dr, mi = self.dr, self.mi
        out = [p[0], p[1], p[2]]
        for j in range(LOBES):
            o = 3 + LOBE_PARAMS * j
            m = p[o + M_OFFSET : o + M_OFFSET + 9]
            q = sum(
                (wo[a] * (m[3 * a] * wi[0] + m[3 * a + 1] * wi[1] + m[3 * a + 2] * wi[2])
                 for a in range(3)),
                start=mi.Float(0.0),
            )  # fmt: skip
            n = dr.maximum(p[o + N_OFFSET], 1.0)
            s = dr.select(q > 0, dr.power(dr.maximum(q, 1e-30), n), 0.0)
            for c in range(3):
                out[c] = dr.fma(p[o + RHO_S_OFFSET + c], s, out[c])
        return self._out([c * wi[2] for c in out])

    def _eval(self, u: Any, v: Any, wi: list[Any], wo: list[Any]) -> Any:
        dr, mi = self.dr, self.mi
        i = dr.minimum(mi.UInt32(u * self.w), self.w - 1)
        j = dr.minimum(mi.UInt32(v * self.h), self.h - 1)
        return self._lafortune(self._gather(self.params, j * self.w + i), wi, wo)

    def _shade(self, wi: list[Any], wo: list[Any]) -> list[Any]:
        return [self._lafortune(self._wide(self.params.channels), wi, wo)]


#: The fused class of each portable model kind.
FUSED_MODELS: dict[str, type[FusedBtf]] = {
    c.model_kind: c for c in (FusedNeumip, FusedStudent, FusedLafortune)
}
