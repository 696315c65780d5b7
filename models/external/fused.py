"""A user MLP material (:class:`models.external.mlp.MlpMaterial`) as a fused Dr.Jit kernel.

The network goes through :func:`models.fused_mlp.fused_mlp`, the same unrolled-literal
kernel as the built-in models (``models/brdf/fused.py``, ``models/btf/fused.py``): each SIMD
lane evaluates its own MLP in registers. The encodings, the texture lookups (bilinear and
periodic, texel centres at ``(i + 0.5) / W``) and the analytic part
(:func:`models.brdf.fused.analytic_brdf`, the twin of ``matforge.brdf-model/1``'s ``f_a``)
are traced around it. The reference is :meth:`MlpMaterial.eval` (numpy, float64), matched
to float32 precision (``tests/unit/models/external/test_mlp.py``).
"""

from __future__ import annotations

import types
from typing import Any

import numpy as np

from models.brdf.fused import BakedMaterial, analytic_brdf, specular_weight
from models.external.mlp import MlpMaterial
from models.fused_mlp import DenseLayer, drjit_activation, fused_mlp


class FusedMlp:
    """An MLP material ready to be traced into a Dr.Jit kernel (Mitsuba variant ``mi``)."""

    def __init__(self, material: MlpMaterial, mi: types.ModuleType) -> None:
        import drjit as dr

        self.material = material
        self.mi = mi
        self.dr = dr
        doc = material.doc
        self.kind = doc.kind
        self.layers = tuple(DenseLayer(ly.weight, ly.bias, ly.activation) for ly in doc.layers)
        self.baked: BakedMaterial | None = None
        if doc.analytic is not None:
            a = doc.analytic
            self.baked = BakedMaterial("analytic", doc.name, a.kd, a.eta, a.alpha, (), ())
        # Textures as flat Dr.Jit arrays, one per channel (row-major texels).
        self.textures = [
            ([mi.Float(np.ascontiguousarray(t[c]).reshape(-1)) for c in range(t.shape[0])],
             int(t.shape[1]), int(t.shape[2]))
            for t in doc.textures
        ]  # fmt: skip

    @property
    def alpha(self) -> float | None:
        """The analytic part's GGX width (``None`` without one): the sampling lobe."""
        return None if self.baked is None else self.baked.alpha

    @property
    def specular_weight(self) -> float:
        """GGX-lobe probability of the BSDF's sampling mixture (0 without an analytic part),
        as the built-in hybrid's (:func:`models.brdf.fused.specular_weight`)."""
        b = self.baked
        if b is None or b.kd is None or b.eta is None or b.alpha is None:
            return 0.0
        return specular_weight(b.kd, b.eta, b.alpha)

    # -- building blocks -------------------------------------------------------------------
    def _bilinear(self, k: int, u: Any, v: Any) -> list[Any]:
        dr, mi = self.dr, self.mi
        channels, h, w = self.textures[k]
        x = u * w - 0.5
        y = v * h - 0.5
        x0, y0 = dr.floor(x), dr.floor(y)
        fx, fy = x - x0, y - y0
        i0 = mi.Int32(x0)
        j0 = mi.Int32(y0)
        i0 = dr.select(i0 < 0, i0 + w, i0)  # u, v in [0, 1): x0, y0 >= -1
        j0 = dr.select(j0 < 0, j0 + h, j0)
        i1 = dr.select(i0 + 1 >= w, 0, i0 + 1)
        j1 = dr.select(j0 + 1 >= h, 0, j0 + 1)
        idx = [mi.UInt32(j * w + i) for j, i in ((j0, i0), (j0, i1), (j1, i0), (j1, i1))]
        w00, w01 = (1 - fx) * (1 - fy), fx * (1 - fy)
        w10, w11 = (1 - fx) * fy, fx * fy
        out = []
        for c in channels:
            a, b, cc, d = (dr.gather(mi.Float, c, i) for i in idx)
            out.append(dr.fma(a, w00, dr.fma(b, w01, dr.fma(cc, w10, d * w11))))
        return out

    def _features(self, wi: Any, wo: Any, u: Any, v: Any) -> list[Any]:
        dr = self.dr
        hx, hy, hz = wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]
        inv = dr.rsqrt(dr.maximum(hx * hx + hy * hy + hz * hz, 1e-30))
        h = [hx * inv, hy * inv, hz * inv]
        base: dict[str, list[Any]] = {
            "wi": list(wi), "wo": list(wo), "wi.xy": list(wi[:2]), "wo.xy": list(wo[:2]),
            "h": h, "cos_i": [wi[2]], "cos_o": [wo[2]], "cos_h": [h[2]],
            "cos_d": [wi[0] * h[0] + wi[1] * h[1] + wi[2] * h[2]],
        }  # fmt: skip
        names = {e.input if e.type == "fourier" else e.type for e in self.material.doc.inputs}
        if "d" in names:
            r = dr.sqrt(h[0] * h[0] + h[1] * h[1])
            safe = r > 1e-12
            rinv = dr.rcp(dr.select(safe, r, 1.0))
            cp = dr.select(safe, h[0] * rinv, 1.0)
            sp = dr.select(safe, h[1] * rinv, 0.0)
            x = cp * wi[0] + sp * wi[1]
            y = cp * wi[1] - sp * wi[0]
            base["d"] = [h[2] * x - r * wi[2], y, r * x + h[2] * wi[2]]
        if u is not None:
            base["uv"] = [u, v]
        feats: list[Any] = []
        for e in self.material.doc.inputs:
            if e.type == "texture":
                assert e.index is not None
                feats += self._bilinear(e.index, u, v)
            elif e.type == "fourier":
                assert e.input is not None
                xs = base[e.input]
                for f in e.frequencies:
                    sc = [dr.sincos(x * f) for x in xs]
                    feats += [s for s, _ in sc] + [c for _, c in sc]
            else:
                feats += base[e.type]
        return feats

    # -- evaluation ------------------------------------------------------------------------
    def eval(self, wi: Any, wo: Any, uv: Any = None) -> Any:
        """The material (``mi.Color3f``, lazy) at ``mi.Vector3f`` directions ``wi``, ``wo``
        (local frame, z up; a BTF's ``wi`` is the light) and, for a BTF, ``mi.Point2f``
        patch coordinates ``uv`` (periodic): the BRDF in 1/sr, or the BTF with
        foreshortening; 0 below either horizon."""
        dr, mi = self.dr, self.mi
        doc = self.material.doc
        wi_ = [wi[0], wi[1], wi[2]]
        wo_ = [wo[0], wo[1], wo[2]]
        u = v = None
        if self.kind == "btf":
            if uv is None:
                raise ValueError(f"{self.material.source}: a BTF is evaluated at uv")
            u = uv[0] - dr.floor(uv[0])
            v = uv[1] - dr.floor(uv[1])
        y: list[Any] = []
        if doc.combine != "analytic":
            out = fused_mlp(self.layers, self._features(wi_, wo_, u, v))
            y = [
                drjit_activation(dr, a)(o) for a, o in zip(doc.output_activations, out, strict=True)
            ]
        if doc.combine == "network":
            f = mi.Color3f(*y[:3])
        else:
            assert self.baked is not None
            f_a = analytic_brdf(mi, self.baked, mi.Vector3f(*wi_), mi.Vector3f(*wo_))
            if doc.combine == "analytic":
                f = f_a
            elif doc.combine == "sum":
                f = mi.Color3f(*y[:3]) + f_a
            else:
                f = mi.Color3f(*y[:3]) + mi.Color3f(*y[3:6]) * f_a
        f = dr.maximum(f, 0.0)
        if self.kind == "btf" and doc.foreshortening == "apply":
            f = f * wi_[2]
        above = (wi_[2] > 0.0) & (wo_[2] > 0.0)
        return dr.select(above, f, 0.0)


def fused_of(model: Any, mi: types.ModuleType) -> Any:
    """The fused Dr.Jit evaluator of a ``drjit-fused`` user model: a
    :class:`FusedMlp` for an MLP material, the model's own ``fused(mi)``
    (:class:`models.external.onnx_mlp.FusedOnnx`) for a recognised ONNX graph. Either has
    ``eval(wi, wo, uv=None)``. ``ValueError`` for a model of another runtime."""
    if isinstance(model, MlpMaterial):
        return FusedMlp(model, mi)
    make = getattr(model, "fused", None)
    if make is None:
        raise ValueError(
            f"a {getattr(model, 'runtime', '?')} model has no fused Dr.Jit kernel "
            "(an MLP material or a recognised ONNX graph has)"
        )
    return make(mi)
