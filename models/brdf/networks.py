"""Torch modules of the BRDF models: the hybrid (Eq. 1-3), the fully neural baseline, GGX alone.

De Oliveira et al., "A Hybrid Neural-Microfacet BRDF Model for Real-Time Rendering" (the
paper below). Every model holds a collection of ``M`` materials: shared network weights ``w``
and per-material parameters; it evaluates plain RGB BRDF values in 1/sr (no cosine).

Shapes: ``wi``, ``wo`` are ``(M, B, 3)`` unit directions in the local shading frame (z up),
row ``m`` belonging to material ``m`` (or to ``index[m]``); outputs are ``(M, B, 3)``.

Models
------
``hybrid`` (Eq. 1): ``f_t = f_c + f_g * f_a`` with ``(f_c, f_g) = Psi_w(wi, wo; z)`` (Eq. 2).
    The MLP input is ``[wi.xyz, wo.xyz, z]`` (Cartesian, Sec. 3.2), ``depth`` hidden ReLU
    layers of ``width`` units, 6 outputs: ``f_c = exp(out[0:3])`` and
    ``f_g = sigmoid(out[3:6])``. ``f_a`` is Eq. 3, Lambert + GGX (see :func:`analytic_brdf`).
``neural``: the fully neural baseline of Zeltner et al. 2024 as the paper re-implements it
    (Sec. 4.1): a per-material latent code replaces the encoder, and a frame module maps the
    code to :data:`NEURAL_FRAMES` learned shading frames that transform the input directions.
    MLP input: ``[R_1 wi, R_1 wo, ..., R_F wi, R_F wo, z]``; 3 outputs, ``f = exp(out)``.
    Simplification (stated): the frame module is one linear layer ``z -> 6 F`` numbers (a
    normal and a tangent per frame, orthonormalised by Gram-Schmidt); Zeltner et al. decode
    frames with a small MLP from a spatially varying latent, which is moot here because one
    homogeneous material has one constant code, hence constant frames.
``analytic``: ``f = f_a`` (GGX + Lambert alone).

Parameter constraints (per material, stored as unconstrained ``raw_*`` tensors):

=========  =====  =========================================================================
name       size   map from the raw value ``r`` (``s = sigmoid(r)``)
=========  =====  =========================================================================
``kd``     3      ``s``: diffuse albedo in [0, 1]^3 (Eq. 3)
``eta``    3      ``1 + 9 s``: real RGB index of refraction in [1, 10]^3 (Eq. 3)
``alpha``  1      ``ALPHA_MIN ** (1 - s)``: GGX width in [1e-3, 1], uniform in log(alpha),
                  so that sharp metals (alpha ~ 0.03) are as easy to reach as rough ones
``z``      l      identity: the latent code
=========  =====  =========================================================================

Per-material parameter accounting (what "equal per-material parameters" means here): the
hybrid stores ``7 + l`` floats per material (3 kd + 3 eta + 1 isotropic alpha + l), so 11 for
``l = 4`` and 15 for ``l = 8``. The paper quotes 12 and 16 because it counts 8 analytic
parameters (an anisotropic alpha in [0, 1]^2, Sec. 3.2); our tables are isotropic (MERL),
so alpha is one float. The neural baseline gets a latent of the *same* float count,
:func:`equal_neural_latent` ``(l) = l + 7``; the paper's convention (``l + 8``) is available
by setting the neural latent explicitly.

The analytic formulas are thin torch twins of :mod:`materials.microfacet` (GGX ``ndf``,
separable Smith ``smith_g2``, exact Fresnel of a real IOR = ``fresnel_conductor`` with
``k = 0``); ``tests/unit/models/test_brdf_networks.py`` checks them against the numpy ones.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

import torch
from torch import Tensor, nn

ModelType = Literal["hybrid", "neural", "analytic"]
MODEL_TYPES: tuple[str, ...] = ("hybrid", "neural", "analytic")

#: Range of the GGX width (the paper: alpha in [0, 1]); log-uniform parametrisation.
ALPHA_MIN = 1e-3
#: Range of the real RGB index of refraction (Eq. 3: eta in [1, 10]^3).
ETA_MIN, ETA_MAX = 1.0, 10.0
#: Per-material floats of the analytic part: 3 kd + 3 eta + 1 alpha.
ANALYTIC_PARAMS = 7
#: Learned shading frames of the neural baseline (Zeltner et al. 2024; the paper, Sec. 4.1).
NEURAL_FRAMES = 3
#: Initial values: kd, eta, alpha, and the output-head biases (f_c = exp(-4) ~ 0.018,
#: f_g = sigmoid(2) ~ 0.88: the hybrid starts close to its analytic part; neural exp(-2)).
INIT_KD, INIT_ETA, INIT_ALPHA = 0.3, 1.5, 0.3
INIT_FC_BIAS, INIT_FG_BIAS, INIT_NEURAL_BIAS = -4.0, 2.0, -2.0
#: Standard deviation of the initial latent codes.
INIT_Z_STD = 0.1


def equal_neural_latent(latent_dim: int) -> int:
    """The neural latent size with the hybrid's per-material float count: ``l + 7``."""
    return latent_dim + ANALYTIC_PARAMS


@dataclass(frozen=True)
class Architecture:
    """What a model is, independent of its weights (written into ``model.json``).

    ``latent_dim`` is the model's own code size: ``l`` for the hybrid, the whole code for the
    neural baseline, 0 for the analytic model (which has no network: width = depth = 0).
    """

    model: ModelType
    width: int
    depth: int
    latent_dim: int

    def __post_init__(self) -> None:
        if self.model not in MODEL_TYPES:
            raise ValueError(f"model must be one of {MODEL_TYPES}, got {self.model!r}")
        if self.model == "analytic":
            if (self.width, self.depth, self.latent_dim) != (0, 0, 0):
                raise ValueError("the analytic model has no network: width = depth = latent = 0")
        elif self.width < 1 or self.depth < 1 or self.latent_dim < 1:
            raise ValueError("width, depth and latent_dim must be positive")

    @property
    def input_dim(self) -> int:
        """MLP inputs: 6 directions + l (hybrid), 6 per frame + l (neural)."""
        if self.model == "hybrid":
            return 6 + self.latent_dim
        if self.model == "neural":
            return 6 * NEURAL_FRAMES + self.latent_dim
        return 0

    @property
    def output_dim(self) -> int:
        """MLP outputs: 6 (f_c, f_g) for the hybrid, 3 for the neural baseline."""
        return {"hybrid": 6, "neural": 3, "analytic": 0}[self.model]

    @property
    def per_material_params(self) -> int:
        """Floats stored per material (see the module docstring)."""
        if self.model == "neural":
            return self.latent_dim
        return ANALYTIC_PARAMS + self.latent_dim

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


# -- analytic part: torch twins of materials.microfacet ----------------------------------------


def ggx_ndf(cos_h: Tensor, alpha: Tensor) -> Tensor:
    """GGX ``D(h) = alpha^2 / (pi (cos^2 (alpha^2 - 1) + 1)^2)`` (Walter et al. 2007, Eq. 33)."""
    a2 = alpha * alpha
    c2 = cos_h.clamp(0.0, 1.0) ** 2
    return a2 / (math.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)


def smith_g1_ggx(cos_v: Tensor, alpha: Tensor) -> Tensor:
    """GGX Smith masking ``2 / (1 + sqrt(1 + alpha^2 tan^2))`` (Walter 2007, Eq. 34)."""
    c2 = cos_v.clamp(1e-12, 1.0) ** 2
    tan2 = (1.0 - c2).clamp_min(0.0) / c2
    return 2.0 / (1.0 + torch.sqrt(1.0 + alpha * alpha * tan2))


def fresnel_real_ior(cos_d: Tensor, eta: Tensor) -> Tensor:
    """Unpolarised Fresnel reflectance of a real IOR ``eta >= 1`` (no total internal
    reflection): ``(r_s^2 + r_p^2) / 2`` with ``cos_t = sqrt(1 - (1 - c^2) / eta^2)``."""
    c = cos_d.clamp(0.0, 1.0)
    ct = torch.sqrt((1.0 - (1.0 - c * c) / (eta * eta)).clamp_min(0.0))
    r_s = (c - eta * ct) / (c + eta * ct)
    r_p = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (r_s * r_s + r_p * r_p)


def analytic_brdf(wi: Tensor, wo: Tensor, kd: Tensor, eta: Tensor, alpha: Tensor) -> Tensor:
    """Eq. 3: ``kd / pi + F(eta) G(alpha) D(alpha) / (4 cos_i cos_o)``, RGB in 1/sr.

    ``wi``, ``wo``: ``(..., 3)`` above the horizon; ``kd``, ``eta``: broadcastable to
    ``(..., 3)``; ``alpha``: broadcastable to ``(..., 1)``. Separable Smith ``G1(wi) G1(wo)``
    and the exact real-IOR Fresnel at ``cos_d = dot(wi, h)``, as :mod:`materials.microfacet`.
    """
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp_min(1e-30)
    cos_i, cos_o = wi[..., 2:3], wo[..., 2:3]
    cos_d = (wi * h).sum(dim=-1, keepdim=True)
    d = ggx_ndf(h[..., 2:3], alpha)
    g = smith_g1_ggx(cos_i, alpha) * smith_g1_ggx(cos_o, alpha)
    spec = d * g / (4.0 * cos_i * cos_o)
    return kd / math.pi + spec * fresnel_real_ior(cos_d, eta)


# -- constraints -------------------------------------------------------------------------------


def kd_from_raw(raw: Tensor) -> Tensor:
    return torch.sigmoid(raw)


def eta_from_raw(raw: Tensor) -> Tensor:
    return ETA_MIN + (ETA_MAX - ETA_MIN) * torch.sigmoid(raw)


def alpha_from_raw(raw: Tensor) -> Tensor:
    return torch.exp(math.log(ALPHA_MIN) * (1.0 - torch.sigmoid(raw)))


def _logit(p: Tensor) -> Tensor:
    p = p.clamp(1e-6, 1.0 - 1e-6)
    return torch.log(p) - torch.log1p(-p)


def raw_from_constrained(kd: Tensor, eta: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Inverse of the constraints (clamped just inside the ranges)."""
    s_alpha = 1.0 - torch.log(alpha.clamp(ALPHA_MIN, 1.0)) / math.log(ALPHA_MIN)
    return _logit(kd), _logit((eta - ETA_MIN) / (ETA_MAX - ETA_MIN)), _logit(s_alpha)


# -- modules -----------------------------------------------------------------------------------


class MLP(nn.Module):
    """``depth`` hidden ReLU layers of ``width`` units and a linear output layer."""

    def __init__(self, n_in: int, width: int, depth: int, n_out: int) -> None:
        super().__init__()
        sizes = [n_in] + [width] * depth + [n_out]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes, sizes[1:], strict=False))

    def linears(self) -> list[nn.Linear]:
        """The linear layers, input first (``depth + 1`` of them)."""
        return [m for m in self.layers if isinstance(m, nn.Linear)]

    def forward(self, x: Tensor) -> Tensor:
        layers = self.linears()
        for i, layer in enumerate(layers):
            x = layer(x)
            if i < len(layers) - 1:
                x = torch.relu(x)
        return x

    def reset(self, generator: torch.Generator) -> None:
        """PyTorch's default ``nn.Linear`` initialisation, drawn from ``generator``."""
        for layer in self.linears():
            nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
            bound = 1.0 / math.sqrt(layer.in_features)
            nn.init.uniform_(layer.bias, -bound, bound, generator=generator)


@dataclass
class BrdfOutput:
    """``f``: the model's BRDF; ``f_a``: its analytic part (hybrid, analytic); ``f_c``,
    ``f_g``: the hybrid's correction and gate. All ``(M, B, 3)``."""

    f: Tensor
    f_a: Tensor | None = None
    f_c: Tensor | None = None
    f_g: Tensor | None = None


class BrdfModel(nn.Module):
    """A collection of ``n_materials`` materials sharing one network (if any).

    Per-material tensors are ``(M, k)`` parameters; :meth:`network_parameters` and
    :meth:`material_parameters` split them for freezing and weight decay.
    """

    def __init__(self, arch: Architecture, n_materials: int) -> None:
        super().__init__()
        if n_materials < 1:
            raise ValueError("a model needs at least one material")
        self.arch = arch
        self.n_materials = n_materials
        m = n_materials
        self.mlp: MLP | None = None
        self.frame: nn.Linear | None = None
        if arch.model in ("hybrid", "analytic"):
            self.raw_kd = nn.Parameter(torch.zeros(m, 3))
            self.raw_eta = nn.Parameter(torch.zeros(m, 3))
            self.raw_alpha = nn.Parameter(torch.zeros(m, 1))
        if arch.model != "analytic":
            self.z = nn.Parameter(torch.zeros(m, arch.latent_dim))
            self.mlp = MLP(arch.input_dim, arch.width, arch.depth, arch.output_dim)
        if arch.model == "neural":
            self.frame = nn.Linear(arch.latent_dim, 6 * NEURAL_FRAMES)

    # -- parameters ----------------------------------------------------------------------------
    def network_parameters(self) -> list[nn.Parameter]:
        """The shared weights ``w`` (empty for the analytic model)."""
        mods = [m for m in (self.mlp, self.frame) if m is not None]
        return [p for mod in mods for p in mod.parameters()]

    def material_parameters(self) -> list[nn.Parameter]:
        """The per-material ``(p, z)``: ``raw_kd``, ``raw_eta``, ``raw_alpha``, ``z`` as present."""
        names = ("raw_kd", "raw_eta", "raw_alpha", "z")
        return [getattr(self, n) for n in names if hasattr(self, n)]

    def reset(self, generator: torch.Generator) -> None:
        """Initialise every parameter from ``generator`` (deterministic)."""
        with torch.no_grad():
            if hasattr(self, "raw_kd"):
                n = self.n_materials
                kd, eta, alpha = raw_from_constrained(
                    torch.full((n, 3), INIT_KD),
                    torch.full((n, 3), INIT_ETA),
                    torch.full((n, 1), INIT_ALPHA),
                )
                self.raw_kd.copy_(kd)
                self.raw_eta.copy_(eta)
                self.raw_alpha.copy_(alpha)
            if hasattr(self, "z"):
                self.z.copy_(torch.randn(self.z.shape, generator=generator) * INIT_Z_STD)
            if self.mlp is not None:
                self.mlp.reset(generator)
                out = self.mlp.linears()[-1].bias
                if self.arch.model == "hybrid":
                    out[:3].fill_(INIT_FC_BIAS)
                    out[3:].fill_(INIT_FG_BIAS)
                else:
                    out.fill_(INIT_NEURAL_BIAS)
            if self.frame is not None:
                nn.init.uniform_(self.frame.weight, -0.1, 0.1, generator=generator)
                # Every frame starts as the identity: normal (0, 0, 1), tangent (1, 0, 0).
                self.frame.bias.copy_(torch.tensor([0.0, 0.0, 1.0, 1.0, 0.0, 0.0] * NEURAL_FRAMES))

    # -- per-material values -------------------------------------------------------------------
    def analytic_params(self, index: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Constrained ``(kd (M, 3), eta (M, 3), alpha (M, 1))``."""
        return (
            kd_from_raw(_rows(self.raw_kd, index)),
            eta_from_raw(_rows(self.raw_eta, index)),
            alpha_from_raw(_rows(self.raw_alpha, index)),
        )

    def frames(self, z: Tensor) -> Tensor:
        """Neural baseline: ``(M, F, 3, 3)`` rows ``(t, b, n)`` of each learned frame."""
        assert self.frame is not None
        raw = self.frame(z).reshape(z.shape[0], NEURAL_FRAMES, 2, 3)
        n = nn.functional.normalize(raw[:, :, 0], dim=-1, eps=1e-12)
        t = raw[:, :, 1] - (raw[:, :, 1] * n).sum(-1, keepdim=True) * n
        t = nn.functional.normalize(t, dim=-1, eps=1e-12)
        b = torch.linalg.cross(n, t, dim=-1)
        return torch.stack([t, b, n], dim=-2)

    def forward(self, wi: Tensor, wo: Tensor, index: Tensor | None = None) -> BrdfOutput:
        """Evaluate materials ``index`` (default: all, in order) at ``(M, B, 3)`` pairs."""
        kind = self.arch.model
        if kind != "neural":
            kd, eta, alpha = self.analytic_params(index)
            f_a = analytic_brdf(wi, wo, kd[:, None], eta[:, None], alpha[:, None])
            if kind == "analytic":
                return BrdfOutput(f=f_a, f_a=f_a)
        assert self.mlp is not None
        z = _rows(self.z, index)
        zb = z[:, None, :].expand(wi.shape[0], wi.shape[1], z.shape[-1])
        if kind == "hybrid":
            out = self.mlp(torch.cat([wi, wo, zb], dim=-1))
            f_c, f_g = torch.exp(out[..., :3]), torch.sigmoid(out[..., 3:])
            return BrdfOutput(f=f_c + f_g * f_a, f_a=f_a, f_c=f_c, f_g=f_g)
        rot = self.frames(z)  # (M, F, 3, 3)
        li = torch.einsum("mfij,mbj->mbfi", rot, wi)
        lo = torch.einsum("mfij,mbj->mbfi", rot, wo)
        x = torch.cat([li, lo], dim=-1).reshape(wi.shape[0], wi.shape[1], 6 * NEURAL_FRAMES)
        return BrdfOutput(f=torch.exp(self.mlp(torch.cat([x, zb], dim=-1))))


def _rows(t: Tensor, index: Tensor | None) -> Tensor:
    return t if index is None else t.index_select(0, index)


def build_model(arch: Architecture, n_materials: int, generator: torch.Generator) -> BrdfModel:
    """A freshly initialised model of ``n_materials`` materials (deterministic in ``generator``)."""
    model = BrdfModel(arch, n_materials)
    model.reset(generator)
    return model


def copy_network(dst: BrdfModel, src: BrdfModel) -> None:
    """Copy the shared weights ``w`` of ``src`` into ``dst`` (same architecture)."""
    if dst.arch != src.arch:
        raise ValueError(f"architectures differ: {dst.arch} and {src.arch}")
    with torch.no_grad():
        for a, b in zip(dst.network_parameters(), src.network_parameters(), strict=True):
            a.copy_(b)


def copy_materials(
    dst: BrdfModel, dst_rows: list[int], src: BrdfModel, src_rows: list[int]
) -> None:
    """Copy the per-material ``(p, z)`` of ``src`` rows into ``dst`` rows (same architecture)."""
    if dst.arch != src.arch:
        raise ValueError(f"architectures differ: {dst.arch} and {src.arch}")
    with torch.no_grad():
        for a, b in zip(dst.material_parameters(), src.material_parameters(), strict=True):
            a[dst_rows] = b[src_rows]
