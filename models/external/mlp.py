"""User MLP materials (``matforge.mlp-brdf/1``, ``matforge.mlp-btf/1``): reading, and the
float64 numpy reference evaluator.

The format (``docs/formats.md``; parsed and checked by :mod:`storage.formats.mlp_model`)
describes a network of the user's own architecture: its inputs from a list of encodings of
the directions (and, for a BTF, of latent textures sampled at ``uv``), dense layers with
activations from :data:`models.fused_mlp.ACTIVATIONS`, an output activation per output, and
for a BRDF an optional analytic Lambert + GGX part combined as the hybrid model does
(Eq. 1 of De Oliveira et al.: ``f = f_c + f_g f_a``) or as a plain sum. :meth:`MlpMaterial.eval`
is the reference; the fused Dr.Jit evaluator :class:`models.external.fused.FusedMlp` (the
renderer's path) is tested against it.

Evaluation at ``(wi, wo)`` (unit vectors in the local frame, z up, ``wi`` the light and
``wo`` the view for a BTF), float64:

1. Features, in ``inputs`` order: ``wi``, ``wo`` (x, y, z), ``wi.xy``, ``wo.xy``;
   ``h = normalize(wi + wo)``; ``d``, Rusinkiewicz's difference vector (``wi`` in the
   frame of ``h``: ``d = R_y(-theta_h) R_z(-phi_h) wi``); ``cos_i = wi.z``, ``cos_o =
   wo.z``, ``cos_h = h.z``, ``cos_d = dot(wi, h)``; BTF: ``uv`` (wrapped into [0, 1)),
   ``texture k``: the ``C`` channels of texture ``k`` sampled bilinearly and periodically
   at ``uv``, texel ``[j, i]`` centred at ``((i + 0.5) / W, (j + 0.5) / H)``;
   ``fourier`` of an input ``x`` with frequencies ``f_0 .. f_{K-1}``: ``sin(f_k x)`` (every
   component of ``x``) then ``cos(f_k x)``, for k = 0 .. K-1.
2. ``x_{l+1} = act_l(W_l x_l + b_l)``; then ``y = act_out(x_L)`` per output.
3. ``combine``: ``network`` ``f = y[0:3]``; ``sum`` ``f = y[0:3] + f_a``; ``hybrid`` ``f =
   y[0:3] + y[3:6] f_a``; ``analytic`` ``f = f_a`` (no network). ``f_a = kd / pi + D G F /
   (4 cos_i cos_o)`` exactly as ``matforge.brdf-model/1`` (GGX ``D``, separable Smith
   ``G``, exact Fresnel of the real RGB IOR ``eta`` at ``cos_d``).
4. ``max(f, 0)``; a BTF with ``foreshortening: "apply"`` is multiplied by ``cos_i``; 0 where
   ``wi.z <= 0`` or ``wo.z <= 0``.

A BRDF's value is the plain BRDF (1/sr, no cosine). A BTF's value is in the UBO2014
convention of ``generate.btf``: foreshortening included, so a Lambertian surface is
``albedo / pi * cos(theta_i)`` (``foreshortening: "apply"`` lets a network output the
BRDF-like part alone).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from materials import microfacet as mf
from models.counts import ANALYTIC_FLOATS, BILINEAR_TAPS, FLOAT_BYTES, dense_counts
from storage.errors import FormatError
from storage.formats.mlp_model import FORMATS, MlpDocument, parse_mlp_document

#: The runtime that renders an MLP material (result rows name it).
RUNTIME = "drjit-fused"


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-30)


def difference_vector(wi: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Rusinkiewicz's difference vector: ``wi`` rotated into the frame of ``h`` (``(N, 3)``),
    ``R_y(-theta_h) R_z(-phi_h) wi``, with ``phi_h = 0`` where ``h`` is the normal."""
    r = np.hypot(h[:, 0], h[:, 1])
    safe = r > 1e-12
    cp = np.where(safe, h[:, 0] / np.where(safe, r, 1.0), 1.0)
    sp = np.where(safe, h[:, 1] / np.where(safe, r, 1.0), 0.0)
    x = cp * wi[:, 0] + sp * wi[:, 1]
    y = -sp * wi[:, 0] + cp * wi[:, 1]
    z = wi[:, 2]
    ct, st = h[:, 2], r
    return np.stack([ct * x - st * z, y, st * x + ct * z], axis=1)


def bilinear_periodic(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``(N, C)`` bilinear, periodic samples of a ``(C, H, W)`` texture at ``(N, 2)`` uv
    (texel ``[j, i]`` centred at ``((i + 0.5) / W, (j + 0.5) / H)``, u along columns)."""
    c, h, w = texture.shape
    tex = np.asarray(texture, np.float64)
    x = (uv[:, 0] - np.floor(uv[:, 0])) * w - 0.5
    y = (uv[:, 1] - np.floor(uv[:, 1])) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0, j0 = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h

    def at(j: np.ndarray, i: np.ndarray) -> np.ndarray:
        return tex[:, j, i].T

    return (
        at(j0, i0) * (1 - fx) * (1 - fy)
        + at(j0, i1) * fx * (1 - fy)
        + at(j1, i0) * (1 - fx) * fy
        + at(j1, i1) * fx * fy
    )


def _activation(name: str, x: np.ndarray) -> np.ndarray:
    table: dict[str, Callable[[np.ndarray], np.ndarray]]
    with np.errstate(over="ignore"):
        table = {
            "identity": lambda v: v,
            "relu": lambda v: np.maximum(v, 0.0),
            "leaky_relu": lambda v: np.where(v >= 0.0, v, 0.01 * v),
            "sigmoid": lambda v: 1.0 / (1.0 + np.exp(-v)),
            "exp": np.exp,
            "softplus": lambda v: np.maximum(v, 0.0) + np.log1p(np.exp(-np.abs(v))),
            "tanh": np.tanh,
        }
        return table[name](x)


@dataclass(frozen=True)
class MlpMaterial:
    """A user MLP material, read and checked (see the module docstring).

    Attributes
    ----------
    doc
        The parsed document (:class:`storage.formats.mlp_model.MlpDocument`).
    source
        The file's name, for messages.
    """

    doc: MlpDocument
    source: str = "model.json"

    #: The runtime of the renderer's evaluation.
    runtime: str = RUNTIME

    @property
    def kind(self) -> str:
        """``"brdf"`` or ``"btf"``."""
        return self.doc.kind

    @property
    def param_bytes(self) -> int:
        """Bytes of all parameters at float32 (weights, biases, textures, analytic part):
        everything needed to render it."""
        return 4 * self.doc.param_count

    @property
    def texture_bytes(self) -> int:
        """Bytes of the latent textures at float32 (0 without textures)."""
        return 4 * int(sum(t.size for t in self.doc.textures))

    @property
    def network_bytes(self) -> int:
        """Bytes of everything but the latent textures: the network's weights and biases
        (and the analytic part's parameters)."""
        return self.param_bytes - self.texture_bytes

    @property
    def macs_per_eval(self) -> int:
        """Multiply-adds of the dense layers per evaluation (:mod:`models.counts`)."""
        return dense_counts((ly.weight.shape[1], ly.weight.shape[0]) for ly in self.doc.layers)[0]

    @property
    def bytes_per_eval(self) -> int:
        """Bytes one evaluation reads (:mod:`models.counts`): the weights and biases, the
        analytic part's 7 floats, and 4 texels of every channel of each texture input."""
        net = dense_counts((ly.weight.shape[1], ly.weight.shape[0]) for ly in self.doc.layers)[1]
        taps = sum(
            BILINEAR_TAPS * int(self.doc.textures[e.index].shape[0])
            for e in self.doc.inputs
            if e.type == "texture" and e.index is not None
        )
        analytic = ANALYTIC_FLOATS if self.doc.analytic is not None else 0
        return net + FLOAT_BYTES * (taps + analytic)

    def features(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None) -> np.ndarray:
        """``(N, n_inputs)`` float64 network inputs (step 1 of the module docstring)."""
        h = _normalize(wi + wo)
        base = {
            "wi": wi, "wo": wo, "wi.xy": wi[:, :2], "wo.xy": wo[:, :2], "h": h,
            "d": difference_vector(wi, h), "cos_i": wi[:, 2:3], "cos_o": wo[:, 2:3],
            "cos_h": h[:, 2:3], "cos_d": np.sum(wi * h, axis=1, keepdims=True),
        }  # fmt: skip
        if uv is not None:
            base["uv"] = uv - np.floor(uv)
        cols = []
        for e in self.doc.inputs:
            if e.type == "texture":
                assert uv is not None and e.index is not None
                cols.append(bilinear_periodic(self.doc.textures[e.index], uv))
            elif e.type == "fourier":
                assert e.input is not None
                x = base[e.input]
                for f in e.frequencies:
                    cols += [np.sin(f * x), np.cos(f * x)]
            else:
                cols.append(base[e.type])
        return np.concatenate(cols, axis=1) if cols else np.zeros((len(wi), 0))

    def network(self, x: np.ndarray) -> np.ndarray:
        """The network with its output activations on ``(N, n_inputs)`` features, float64."""
        for layer in self.doc.layers:
            x = _activation(layer.activation, x @ layer.weight.T.astype(np.float64) + layer.bias)
        return np.stack(
            [_activation(a, x[:, k]) for k, a in enumerate(self.doc.output_activations)], axis=1
        )

    def analytic(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_a`` (``(N, 3)``, 1/sr): Lambert + GGX with the exact real-IOR Fresnel."""
        a = self.doc.analytic
        assert a is not None
        eta = np.asarray(a.eta, np.float64)
        spec = mf.specular_brdf(
            wi, wo, a.alpha, lambda c: mf.fresnel_conductor(c, eta, 0.0),
            distribution="ggx", shadowing="separable",
        )  # fmt: skip
        return np.asarray(a.kd, np.float64) / np.pi + spec

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """The material at ``(N, 3)`` pairs (and ``(N, 2)`` ``uv`` for a BTF): ``(N, 3)``
        float64, the BRDF in 1/sr or the BTF (foreshortening included); 0 below either
        horizon."""
        wi = np.asarray(wi, np.float64)
        wo = np.asarray(wo, np.float64)
        if wi.ndim != 2 or wi.shape[1] != 3 or wi.shape != wo.shape:
            raise ValueError(f"wi and wo must both have shape (N, 3), got {wi.shape}, {wo.shape}")
        if self.kind == "btf":
            if uv is None:
                raise ValueError(f"{self.source}: a BTF is evaluated at uv; give uv (N, 2)")
            uv = np.asarray(uv, np.float64)
            if uv.shape != (len(wi), 2):
                raise ValueError(f"uv must have shape ({len(wi)}, 2), got {uv.shape}")
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros((len(wi), 3))
        i, o = wi[above], wo[above]
        u = None if uv is None or self.kind != "btf" else uv[above]
        combine = self.doc.combine
        y = None if combine == "analytic" else self.network(self.features(i, o, u))
        if combine == "network":
            assert y is not None
            f = y[:, 0:3]
        else:
            f_a = self.analytic(i, o)
            if combine == "analytic":
                f = f_a
            elif combine == "sum":
                assert y is not None
                f = y[:, 0:3] + f_a
            else:
                assert y is not None
                f = y[:, 0:3] + y[:, 3:6] * f_a
        f = np.maximum(f, 0.0)
        if self.kind == "btf" and self.doc.foreshortening == "apply":
            f = f * i[:, 2:3]
        out[above] = f
        return out


def mlp_from_document(doc: Any, name: str = "model.json") -> MlpMaterial:
    """An :class:`MlpMaterial` of a parsed JSON document; ``ValueError`` naming ``name``."""
    try:
        return MlpMaterial(parse_mlp_document(doc, name), source=name)
    except FormatError as exc:
        raise ValueError(str(exc)) from None


def read_mlp(path: str | Path) -> MlpMaterial:
    """Read and check an MLP material file; ``ValueError`` naming the file and the problem."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{p.name}: not a readable JSON file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") not in FORMATS:
        known = ", ".join(FORMATS)
        got = doc.get("format") if isinstance(doc, dict) else None
        raise ValueError(f"{p.name}: not an MLP material (format {got!r}; expected {known})")
    return mlp_from_document(doc, p.name)
