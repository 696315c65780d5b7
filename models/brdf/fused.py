"""One material of a trained BRDF model as constants traced into a Dr.Jit kernel.

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering". The
weights and the material's ``z``, ``kd``, ``eta``, ``alpha`` are baked in as literals
(:mod:`models.fused_mlp`), so each SIMD lane evaluates its own MLP. The ``brdf_model``
Mitsuba BSDF (:mod:`evaluators.render.bsdfs.brdf_model`) and the speed report
(:mod:`models.speed`) evaluate a material through :func:`model_brdf`.

Evaluation (plain BRDF ``f`` in 1/sr)
    ``hybrid``: ``f = f_c + f_g f_a`` (Eq. 1) with ``(f_c, f_g) = (exp, sigmoid)`` of the
    MLP's 6 outputs on ``[wi, wo, z]`` (Eq. 2) and ``f_a`` the Lambert + GGX of Eq. 3
    (:func:`analytic_brdf`: separable Smith G, exact Fresnel of a real RGB IOR, as
    :mod:`models.brdf.networks`). ``neural``: ``f = exp(MLP(...))``; its learned frames are
    constant per material and are folded into the first layer (:mod:`models.brdf.portable`
    defines them). ``analytic``: ``f = f_a``. The reference is
    :func:`models.brdf.portable.eval_portable` (numpy), matched to float32 precision.
"""

from __future__ import annotations

import json
import math
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from materials.lobe_fit import SPECULAR_WEIGHT_BOUNDS
from materials.microfacet import fresnel_dielectric, specular_albedo
from models.fused_mlp import DenseLayer, fused_mlp, make_layers


@dataclass(frozen=True)
class BakedMaterial:
    """One material of a model, as constants ready to be traced.

    Attributes
    ----------
    model
        ``"hybrid"``, ``"neural"`` or ``"analytic"``.
    name
        The material's name in the model.
    kd, eta
        ``(3,)`` diffuse albedo in [0, 1] and real RGB IOR >= 1 (``None`` for ``neural``).
    alpha
        GGX width (``None`` for ``neural``).
    layers
        The MLP with its first layer taking ``[wi.xyz, wo.xyz, z]`` (the neural model's
        frames already folded in); empty for ``analytic``.
    z
        The latent code, fed to the MLP as constants (folded into the first bias).
    """

    model: str
    name: str
    kd: tuple[float, float, float] | None
    eta: tuple[float, float, float] | None
    alpha: float | None
    layers: tuple[DenseLayer, ...]
    z: tuple[float, ...]

    @property
    def has_analytic(self) -> bool:
        """Whether the model has an analytic part ``f_a`` (hybrid, analytic)."""
        return self.model != "neural"

    @property
    def specular_weight(self) -> float:
        """Probability that ``sample`` draws from the GGX lobe (see the module docstring)."""
        if self.kd is None or self.eta is None or self.alpha is None:
            return 0.0
        return specular_weight(self.kd, self.eta, self.alpha)


def read_model(path: str | Path) -> dict[str, Any]:
    """Read a ``model.json`` document (``matforge.brdf-model/1``); ``ValueError`` if it is
    not one."""
    from models.brdf import portable  # (imports torch: only when a model is read)

    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{Path(path).name}: not a readable JSON file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != portable.FORMAT:
        raise ValueError(f"{Path(path).name}: not a {portable.FORMAT} model document")
    return doc


def bake_material(doc: dict[str, Any], name: str) -> BakedMaterial:
    """Material ``name`` of a ``model.json`` document as :class:`BakedMaterial`.

    Follows :mod:`models.brdf.portable`: hidden ReLU layers, linear last layer. For the
    neural model the material's constant frames (``portable``'s frame module applied to its
    ``z``) are folded into the first layer, in float64: ``W_wi = sum_j W[:, 6j:6j+3] R_j``
    and ``W_wo = sum_j W[:, 6j+3:6j+6] R_j`` with ``R_j`` the rows ``(t, b, n)`` of frame
    ``j``, so the kernel reads ``[wi, wo, z]`` like the hybrid's. Raises ``ValueError`` for
    an unknown material or a document this evaluator does not understand.
    """
    from models.brdf import portable  # (imports torch: only when a model is read)

    try:
        arch = portable.check_document(doc)
        mat = portable.material_entry(doc, name)
        a = doc["architecture"]
        heads = [(h["slice"], h["activation"]) for h in a["output_heads"]]
        expected = {
            "hybrid": [([0, 3], "exp"), ([3, 6], "sigmoid")],
            "neural": [([0, 3], "exp")],
            "analytic": [],
        }[arch.model]
        if heads != expected or a.get("hidden_activation") not in ("relu", None):
            raise ValueError("unsupported output heads or hidden activation")
        layers: tuple[DenseLayer, ...] = ()
        z = tuple(float(v) for v in mat["z"])
        if arch.model != "analytic":
            net = doc["network"]
            params = [
                (np.asarray(ly["weight"], np.float64), np.asarray(ly["bias"], np.float64))
                for ly in net["layers"]
            ]
            if arch.model == "neural":
                w0, n_f = params[0][0], int(a["frames"])
                rot = portable.neural_frames(net["frame"], np.asarray(z, np.float64))
                w_i = sum(w0[:, 6 * j : 6 * j + 3] @ rot[j] for j in range(n_f))
                w_o = sum(w0[:, 6 * j + 3 : 6 * j + 6] @ rot[j] for j in range(n_f))
                w0 = np.concatenate([w_i, w_o, w0[:, 6 * n_f :]], axis=1)
                params[0] = (w0, params[0][1])
            acts = ["relu"] * (len(params) - 1) + ["identity"]
            layers = tuple(make_layers(params, acts))
            if layers[0].n_in != 6 + len(z) or layers[-1].n_out != 3 * len(expected):
                raise ValueError("network shapes do not match the architecture")
        analytic = arch.model != "neural"
        return BakedMaterial(
            model=arch.model,
            name=name,
            kd=tuple(float(v) for v in mat["kd"]) if analytic else None,  # type: ignore[arg-type]
            eta=tuple(float(v) for v in mat["eta"]) if analytic else None,  # type: ignore[arg-type]
            alpha=float(mat["alpha"]) if analytic else None,
            layers=layers,
            z=z,
        )
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"malformed model document ({type(exc).__name__}: {exc})") from None


def specular_weight(
    kd: tuple[float, float, float], eta: tuple[float, float, float], alpha: float
) -> float:
    """GGX-lobe probability of the sampling mixture: ``E_s / (E_s + E_d)``, clipped.

    At normal incidence, ``E_s = F(1) A(alpha)`` with ``A`` the unit-Fresnel GGX albedo
    (:func:`materials.microfacet.specular_albedo`) and ``F(1)`` the channel-mean Fresnel
    reflectance of ``eta``; ``E_d`` is the channel-mean ``kd`` (the Lambert albedo).
    Clipped to :data:`materials.lobe_fit.SPECULAR_WEIGHT_BOUNDS`.
    """
    f0 = float(np.mean([fresnel_dielectric(np.array(1.0), e) for e in eta]))
    e_s = f0 * float(specular_albedo(np.array([1.0]), alpha, np.ones_like)[0])
    e_d = float(np.mean(kd))
    lo, hi = SPECULAR_WEIGHT_BOUNDS
    return float(np.clip(e_s / (e_s + e_d), lo, hi)) if e_s + e_d > 0 else 0.5


def analytic_brdf(mi: types.ModuleType, m: BakedMaterial, wi: Any, wo: Any) -> Any:
    """Eq. 3 in Dr.Jit: ``kd / pi + F(eta) G1(wi) G1(wo) D / (4 cos_i cos_o)``, ``Color3f``.

    The twin of :func:`models.brdf.networks.analytic_brdf` (GGX ``D`` and Smith ``G1`` of
    Walter et al. 2007, Eqs. 33-34; exact unpolarised Fresnel of a real IOR). ``wi``, ``wo``:
    ``mi.Vector3f`` above the horizon (the caller masks the rest).
    """
    import drjit as dr

    assert m.kd is not None and m.eta is not None and m.alpha is not None
    a2 = m.alpha * m.alpha
    # D from the unnormalised half vector H: with s2 = Hx^2 + Hy^2 and c2 = Hz^2,
    # D = a^2 |H|^4 / (pi (s2 + a^2 c2)^2), the same value as Eq. 33 of Walter et al. but
    # without the cancellation in 1 - cos^2 that costs float32 digits near the peak.
    hv = wi + wo
    s2 = dr.square(hv.x) + dr.square(hv.y)
    c2 = dr.square(dr.maximum(hv.z, 0.0))
    d = a2 * dr.square(s2 + c2) / (math.pi * dr.square(s2 + a2 * c2))

    def g1(v: Any) -> Any:
        # tan^2 = (x^2 + y^2) / z^2 for a unit vector, again without 1 - cos^2.
        tan2 = (dr.square(v.x) + dr.square(v.y)) / dr.square(dr.maximum(v.z, 1e-12))
        return 2.0 / (1.0 + dr.sqrt(1.0 + a2 * tan2))

    spec = d * g1(wi) * g1(wo) / (4.0 * wi.z * wo.z)
    c = dr.clip(dr.dot(wi, dr.normalize(hv)), 0.0, 1.0)
    channels = []
    for k in range(3):
        eta = m.eta[k]
        ct = dr.sqrt(dr.maximum(1.0 - (1.0 - c * c) / (eta * eta), 0.0))
        r_s = (c - eta * ct) / (c + eta * ct)
        r_p = (eta * c - ct) / (eta * c + ct)
        fresnel = 0.5 * (r_s * r_s + r_p * r_p)
        channels.append(m.kd[k] / math.pi + spec * fresnel)
    return mi.Color3f(*channels)


def model_brdf(
    mi: types.ModuleType, m: BakedMaterial, wi: Any, wo: Any, neural: bool = True
) -> Any:
    """The material's BRDF ``f(wi, wo)`` (1/sr, ``mi.Color3f``, no cosine), traced lazily.

    ``neural=False`` gives the analytic part ``f_a`` alone (hybrid and analytic models).
    No horizon test: the caller masks pairs with ``wi.z <= 0`` or ``wo.z <= 0``.
    """
    import drjit as dr

    if m.model == "analytic" or (not neural and m.has_analytic):
        return analytic_brdf(mi, m, wi, wo)
    if not neural:
        raise ValueError(f"{m.name}: a {m.model} model has no analytic part to fall back on")
    out = fused_mlp(m.layers, [wi.x, wi.y, wi.z, wo.x, wo.y, wo.z, *m.z])
    if m.model == "neural":
        return mi.Color3f(*(dr.exp(v) for v in out))
    f_a = analytic_brdf(mi, m, wi, wo)
    f_c = mi.Color3f(*(dr.exp(v) for v in out[:3]))
    f_g = mi.Color3f(*(dr.rcp(1.0 + dr.exp(-v)) for v in out[3:6]))
    return f_c + f_g * f_a


def brdf_counts(model: str, width: int, depth: int) -> dict[str, int]:
    """``{"macs_per_eval", "bytes_per_eval"}`` of one material of a ``train.brdf`` model as
    its fused kernel runs it (:mod:`models.counts`; :func:`bake_material`): the MLP reads
    the 6 direction components (the latent ``z`` folded into the first bias, the neural
    model's frames into its first layer), 6 outputs for the hybrid (``f_c``, ``f_g``), 3 for
    the neural model; bytes: its weights and biases, and the analytic part's 7 floats
    (hybrid, analytic). The analytic model has no network: 0 multiply-adds."""
    from models.counts import ANALYTIC_FLOATS, FLOAT_BYTES, mlp_macs, mlp_params

    if model == "analytic" or depth <= 0:
        return {"macs_per_eval": 0, "bytes_per_eval": FLOAT_BYTES * ANALYTIC_FLOATS}
    n_out = 6 if model == "hybrid" else 3
    analytic = ANALYTIC_FLOATS if model == "hybrid" else 0
    return {
        "macs_per_eval": mlp_macs(6, width, depth, n_out),
        "bytes_per_eval": FLOAT_BYTES * (mlp_params(6, width, depth, n_out) + analytic),
    }
