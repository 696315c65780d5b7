"""The encoder-decoder network of Chen, Wang & Wang 2024 (Sec. 4.2, Fig. 3), in plain torch.

Encoder (once per material): the normal and orientation maps of one weave tile, 6 channels
``(n_p.xyz, t_p.xyz)`` at ``map_resolution`` squared (row 0 at the top, as the
``generate.fabric`` EXR maps), go through a ResNet-18 without its last stage (``layer4``;
Sec. 4.2: "a modified ResNet-18 without the last residual block"), global-average-pooled to
``4 * encoder_width`` features (256 for the standard width 64). With the appearance
parameters :data:`PARAM_NAMES` they pass a residual MLP (a projection to 128, one residual
block of two FC layers of 128 with a skip before the last leaky ReLU, Fig. 3) to the
``latent_dim`` (64) material latent ``z``.

Decoder (per query): the footprint's one-blob channels (:mod:`models.fabric.encoding`,
3 -> 24) and ``z`` are fused by two FC layers into a spatial feature of ``decoder_width``;
with ``wi.xyz`` and ``wo.xy`` (Sec. 4.2: ``wi.z`` is needed, it is negative for
transmission) the angular decoder of five FC layers with one skip (the output of layer 1 is
added before the activation of layer 3) gives 4 raw outputs in the order of Eq. 7,
``C_warp, C_weft, S_warp, S_weft``. Hidden activations are leaky ReLU (slope 0.01).

Raw outputs to components (:func:`components`): the specular outputs are fitted in the
log space of Eq. 9, ``g(S) = ln(k S + 1)`` with ``k`` = :data:`K_BRDF` for ``wi.z >= 0``
and :data:`K_BTDF` below, so ``S = expm1(max(raw, 0)) / k``; the diffuse ones directly,
``C = max(raw, 0)``, and 0 for light from below (``wi.z < 0``), where the diffuse
component is 0 by definition. The clamps only remove small negative excursions of the fit.

Choices the paper leaves open, and ours:

- **Normalisation**: GroupNorm (8 groups) in place of BatchNorm. A training step sees one
  or a few materials, so batch statistics of one tile would be noisy and differ between
  training and inference; GroupNorm is the same in both modes and deterministic.
- **Periodic padding**: convolutions and the stem's max-pool pad circularly, since a weave
  tile repeats; features then do not depend on where the tile was cut.
- **Encoder parameters**: ``alpha`` and ``beta`` per yarn (Table 1) and the Lambertian
  weight ``w`` of Eq. 1, which our ``generate.fabric`` samples per material and which
  changes the C/S split; ``psi`` and ``u`` are in the maps, ``gap`` and ``T rho`` fixed.
- **Widths**: ``decoder_width`` 64 (paper preset) or 32 (small); ``encoder_width`` 64 is
  the standard ResNet-18, the small preset uses 32 (layer3 then has 128 channels).
- **Map resolution**: 64 px (small; the small ``generate.fabric`` maps, so no resampling)
  or 256 px (paper; its maps): after the stride-16 trunk a 4 x 4 or 16 x 16 grid is pooled.
  Other sizes are resampled (:func:`resample_map`).
- **No yarn-mask channels**: gaps already show in the maps (``n_p = n_s`` and
  ``t_p = +x`` there, ``materials.fabric.yarn``), and warp and weft differ in ``t_p``.

Second-pass options (issue 12; the defaults are the network above, unchanged):

- ``centre_encoding``, ``size_encoding``, ``centre_bins``: the footprint encoding
  (:class:`models.fabric.encoding.SpatialEncoding`: periodic centre one-blob, log size);
- ``param_skip`` 1: the 5 appearance parameters (:data:`PARAM_NAMES`) join ``z`` in the code
  as they are, so the decoder sees alpha, beta and w directly. Without it a small model
  learns one function per pattern and ignores them (BENCHMARKS.md, issue 12: four materials
  of one pattern with beta 0.28-0.90 decode to the same components to 3 digits); with it,
  at the same 6,000-step budget, the decoder ignores them too (measured there), so this is
  an option to try at larger budgets, not a fix;
- ``phase_channels`` ``P > 0``: **phase-aware features**. Circular padding and global
  pooling make ``z`` nearly independent of where the tile was cut, so the decoder can learn
  a seen pattern's layout only by memorising it against the one-blob centre. Here the
  trunk's ``layer2`` map (stride 8: ``R/8`` squared cells, ``2 * encoder_width`` channels)
  goes through a 1x1 convolution to ``P`` channels, and the decoder samples it bilinearly,
  wrapping at the tile border, at the footprint centre
  (:func:`models.fabric.encoding.phase_taps`); the ``P`` sampled values join ``z`` and the
  footprint encoding at ``spatial1``. The circular convolutions are shift-equivariant, so
  rolling the maps by a multiple of 8 px rolls the sampled features with them.
  The material's **code** is then ``z`` followed by the ``(P, R/8, R/8)`` grid flattened
  (C order): what :meth:`Encoder.forward` returns, ``model.json`` stores as a material's
  ``latent``, and the fused decoder reads (``Architecture.code_dim`` values; with
  ``P = 0`` the code is ``z``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn
from torch.nn import functional as F

from models.fabric.encoding import BINS, SpatialEncoding, phase_taps, spatial_features, torch_ops

#: Encoder appearance inputs, in order (pairs are (warp, weft) in ``materials.json``).
PARAM_NAMES: tuple[str, ...] = ("alpha_warp", "alpha_weft", "beta_warp", "beta_weft", "w")
#: Eq. 9: the log mapping's ``k`` for BRDF (``wi.z >= 0``) and BTDF (``wi.z < 0``) queries.
K_BRDF, K_BTDF = 100.0, 1000.0
#: Slope of the leaky ReLUs (torch's default; :data:`models.fused_mlp.LEAKY_SLOPE`).
LEAKY = 0.01
#: Output components, Eq. 7.
COMPONENTS: tuple[str, ...] = ("C_warp", "C_weft", "S_warp", "S_weft")
#: Angular inputs of the decoder (Sec. 4.2: wi has three channels, wo two).
ANGULAR_INPUTS: tuple[str, ...] = ("wi.x", "wi.y", "wi.z", "wo.x", "wo.y")


@dataclass(frozen=True)
class Architecture:
    """Sizes of one network (see the module docstring)."""

    encoder_width: int = 64
    map_resolution: int = 64
    latent_dim: int = 64
    mlp_width: int = 128
    decoder_width: int = 64
    bins: int = BINS
    centre_encoding: str = "one_blob"
    size_encoding: str = "strata"
    centre_bins: int = BINS
    phase_channels: int = 0
    param_skip: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The fields; the second-pass ones only where they differ from the default (so a
        default network's ``model.json`` and ``model.pt`` keep their bytes)."""
        d = asdict(self)
        default = Architecture()
        for k in _SECOND_PASS:
            if d[k] == getattr(default, k):
                del d[k]
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Architecture:
        fields: dict[str, Any] = {
            k: (str(d[k]) if isinstance(v, str) else int(d[k]))
            for k, v in asdict(cls()).items()
            if k in d
        }
        return cls(**fields)

    @property
    def encoding(self) -> SpatialEncoding:
        """The footprint encoding of the decoder."""
        return SpatialEncoding(
            self.centre_encoding, self.size_encoding, self.bins, self.centre_bins
        )

    @property
    def phase_grid(self) -> int:
        """Cells per side of the phase feature grid (``map_resolution / 8``; 0 when off)."""
        return self.map_resolution // 8 if self.phase_channels else 0

    @property
    def z_dim(self) -> int:
        """Values of the code's global part: ``z``, plus the 5 parameters with
        ``param_skip``."""
        return self.latent_dim + (len(PARAM_NAMES) if self.param_skip else 0)

    @property
    def code_dim(self) -> int:
        """Values of a material's code: ``z_dim + phase_channels * phase_grid^2``."""
        return self.z_dim + self.phase_channels * self.phase_grid**2


#: Architecture fields of the second pass (left out of :meth:`Architecture.as_dict` at
#: their defaults).
_SECOND_PASS = ("centre_encoding", "size_encoding", "centre_bins", "phase_channels", "param_skip")


def param_vector(record: Mapping[str, Any]) -> np.ndarray:
    """``(5,)`` float32 encoder parameters from a ``materials.json`` ``params`` record."""
    return np.array(
        [record["alpha"][0], record["alpha"][1], record["beta"][0], record["beta"][1], record["w"]],
        dtype=np.float32,
    )


def resample_map(image: np.ndarray, resolution: int) -> np.ndarray:
    """A periodic ``(H, W, 3)`` tile map resampled to ``(resolution, resolution, 3)`` float32.

    An integer down-scale averages boxes (area filter); anything else samples bilinearly
    at the target pixel centres with wrap-around (the tile is periodic).
    """
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"a map must have shape (H, W, 3), got {img.shape}")
    h, w = img.shape[:2]
    if (h, w) == (resolution, resolution):
        return np.ascontiguousarray(img)
    if h % resolution == 0 and w % resolution == 0:
        fy, fx = h // resolution, w // resolution
        return (
            img.reshape(resolution, fy, resolution, fx, 3)
            .mean(axis=(1, 3), dtype=np.float64)
            .astype(np.float32)
        )
    out = img.astype(np.float64)
    for axis, n in ((0, h), (1, w)):
        pos = (np.arange(resolution) + 0.5) * n / resolution - 0.5
        i0 = np.floor(pos).astype(np.int64)
        t = (pos - i0).reshape([-1 if a == axis else 1 for a in range(3)])
        a = np.take(out, i0 % n, axis=axis)
        b = np.take(out, (i0 + 1) % n, axis=axis)
        out = a * (1.0 - t) + b * t
    return out.astype(np.float32)


def map_tensor(normal: np.ndarray, orientation: np.ndarray, resolution: int) -> np.ndarray:
    """``(6, R, R)`` float32 encoder input: resampled normal then orientation channels."""
    n = resample_map(normal, resolution)
    t = resample_map(orientation, resolution)
    return np.ascontiguousarray(np.concatenate([n, t], axis=2).transpose(2, 0, 1))


def _norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(8, channels)


def _conv3x3(c_in: int, c_out: int, stride: int) -> nn.Conv2d:
    return nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False, padding_mode="circular")


class BasicBlock(nn.Module):
    """ResNet basic block (He et al. 2016): two 3x3 convolutions and an identity skip."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = _conv3x3(c_in, c_out, stride)
        self.norm1 = _norm(c_out)
        self.conv2 = _conv3x3(c_out, c_out, 1)
        self.norm2 = _norm(c_out)
        self.down: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.down = nn.Sequential(
                nn.Conv2d(c_in, c_out, kernel_size=1, stride=stride, bias=False), _norm(c_out)
            )

    def forward(self, x: Tensor) -> Tensor:
        h = F.relu(self.norm1(self.conv1(x)))
        h = self.norm2(self.conv2(h))
        return F.relu(h + self.down(x))


class ResNet18Trunk(nn.Module):
    """ResNet-18 up to ``layer3`` (two blocks per stage), global average pooled.

    ``(B, in_channels, R, R)`` -> ``(B, 4 * width)``; the receptive field of a pooled
    feature covers the whole tile for ``R <= 128`` (stride 16 after layer3).
    """

    def __init__(self, in_channels: int = 6, width: int = 64) -> None:
        super().__init__()
        self.stem = nn.Conv2d(
            in_channels, width, 7, stride=2, padding=3, bias=False, padding_mode="circular"
        )
        self.stem_norm = _norm(width)
        self.layer1 = nn.Sequential(BasicBlock(width, width, 1), BasicBlock(width, width, 1))
        self.layer2 = nn.Sequential(
            BasicBlock(width, 2 * width, 2), BasicBlock(2 * width, 2 * width, 1)
        )
        self.layer3 = nn.Sequential(
            BasicBlock(2 * width, 4 * width, 2), BasicBlock(4 * width, 4 * width, 1)
        )
        self.out_features = 4 * width

    def forward(self, x: Tensor) -> Tensor:
        return self.features(x)[1]

    def features(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(layer2 map (B, 2 width, R/8, R/8), pooled (B, 4 width))``."""
        h = F.relu(self.stem_norm(self.stem(x)))
        h = F.max_pool2d(F.pad(h, (1, 1, 1, 1), mode="circular"), 3, stride=2)
        mid = self.layer2(self.layer1(h))
        return mid, self.layer3(mid).mean(dim=(2, 3))


class Encoder(nn.Module):
    """Maps and parameters -> material latent ``z`` (Sec. 4.2, "Encoder")."""

    def __init__(self, arch: Architecture) -> None:
        super().__init__()
        self.trunk = ResNet18Trunk(6, arch.encoder_width)
        self.proj = nn.Linear(self.trunk.out_features + len(PARAM_NAMES), arch.mlp_width)
        self.fc1 = nn.Linear(arch.mlp_width, arch.mlp_width)
        self.fc2 = nn.Linear(arch.mlp_width, arch.mlp_width)
        self.out = nn.Linear(arch.mlp_width, arch.latent_dim)
        self.param_skip = bool(arch.param_skip)
        self.phase: nn.Module | None = None
        if arch.phase_channels:
            self.phase = nn.Conv2d(2 * arch.encoder_width, arch.phase_channels, 1)

    def forward(self, maps: Tensor, params: Tensor) -> Tensor:
        """``maps`` ``(B, 6, R, R)``, ``params`` ``(B, 5)`` -> codes ``(B, code_dim)``: the
        latent ``z``, then the phase grid flattened when ``phase_channels > 0``."""
        mid, pooled = self.trunk.features(maps)
        h = F.leaky_relu(self.proj(torch.cat([pooled, params], dim=1)), LEAKY)
        r = self.fc2(F.leaky_relu(self.fc1(h), LEAKY))
        parts = [self.out(F.leaky_relu(r + h, LEAKY))]
        if self.param_skip:
            parts.append(params)
        if self.phase is not None:
            parts.append(self.phase(mid).flatten(1))
        return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)


class Decoder(nn.Module):
    """Latent and query -> 4 raw outputs (Sec. 4.2, "Decoder"); layer names as in model.json."""

    def __init__(self, arch: Architecture) -> None:
        super().__init__()
        w = arch.decoder_width
        self.arch = arch
        self.spatial1 = nn.Linear(arch.z_dim + arch.phase_channels + arch.encoding.channels, w)
        self.spatial2 = nn.Linear(w, w)
        self.angular1 = nn.Linear(w + len(ANGULAR_INPUTS), w)
        self.angular2 = nn.Linear(w, w)
        self.angular3 = nn.Linear(w, w)
        self.angular4 = nn.Linear(w, w)
        self.angular5 = nn.Linear(w, len(COMPONENTS))

    def forward(self, code: Tensor, query: Tensor) -> Tensor:
        """Raw outputs ``(N, 4)`` of material codes ``(N, code_dim)`` at queries ``(N, 8)``:
        ``cx, cy, size, wi.xyz, wo.xy``."""
        a = self.arch
        ops = torch_ops()
        feats = spatial_features(ops, query[:, 0], query[:, 1], query[:, 2], enc=a.encoding)
        parts = [code[:, : a.z_dim]]
        if a.phase_channels:
            g = a.phase_grid
            # Channel p's grid starts at latent_dim + p g^2 (gathered in place: ``code``
            # may be one material's code expanded over the queries).
            base = a.z_dim + g * g * torch.arange(a.phase_channels, device=code.device)
            sampled = torch.zeros(len(code), a.phase_channels, dtype=code.dtype, device=code.device)
            for idx, wt in phase_taps(ops, query[:, 0], query[:, 1], g, g):
                cols = base[None, :] + idx.long()[:, None]
                sampled = sampled + wt[:, None] * code.gather(1, cols)
            parts.append(sampled)
        x = torch.cat([*parts, torch.stack(feats, dim=1)], dim=1)
        s = F.leaky_relu(self.spatial2(F.leaky_relu(self.spatial1(x), LEAKY)), LEAKY)
        h1 = F.leaky_relu(self.angular1(torch.cat([s, query[:, 3:8]], dim=1)), LEAKY)
        h3 = F.leaky_relu(self.angular3(F.leaky_relu(self.angular2(h1), LEAKY)) + h1, LEAKY)
        return self.angular5(F.leaky_relu(self.angular4(h3), LEAKY))


#: Decoder layers in evaluation order (the names of ``model.json``'s ``decoder``).
DECODER_LAYERS: tuple[str, ...] = (
    "spatial1",
    "spatial2",
    "angular1",
    "angular2",
    "angular3",
    "angular4",
    "angular5",
)


class FabricNetwork(nn.Module):
    """Encoder and decoder together; the trained module of ``train.fabric``."""

    def __init__(self, arch: Architecture) -> None:
        super().__init__()
        self.arch = arch
        self.encoder = Encoder(arch)
        self.decoder = Decoder(arch)

    def forward(self, maps: Tensor, params: Tensor, index: Tensor, query: Tensor) -> Tensor:
        """Raw outputs ``(N, 4)``: query ``n`` belongs to material ``index[n]`` of the
        ``(B, ...)`` ``maps`` and ``params``."""
        z = self.encoder(maps, params)
        return self.decoder(z.index_select(0, index), query)


def log_k(wi_z: Tensor) -> Tensor:
    """Eq. 9's ``k`` per query: :data:`K_BTDF` where ``wi.z < 0``, else :data:`K_BRDF`."""
    return torch.where(wi_z < 0, K_BTDF, K_BRDF).to(wi_z.dtype)


def components(raw: Tensor, wi_z: Tensor) -> Tensor:
    """Raw outputs ``(N, 4)`` to the components of Eq. 7 (see the module docstring). C is 0
    for light from below (``wi.z < 0``), as the diffuse component is by definition
    (:func:`materials.fabric.shading.diffuse_response`): no spurious diffuse transmission."""
    c = torch.where(wi_z[:, None] < 0, 0.0, raw[:, :2].clamp_min(0.0))
    s = torch.expm1(raw[:, 2:].clamp_min(0.0)) / log_k(wi_z)[:, None]
    return torch.cat([c, s], dim=1)


def components_numpy(raw: np.ndarray, wi_z: np.ndarray) -> np.ndarray:
    """numpy twin of :func:`components`: ``(N, 4)`` float32."""
    k = np.where(np.asarray(wi_z) < 0, K_BTDF, K_BRDF).astype(np.float32)[:, None]
    c = np.where(np.asarray(wi_z)[:, None] < 0, 0.0, np.maximum(raw[:, :2], 0.0))
    s = np.expm1(np.maximum(raw[:, 2:], 0.0)) / k
    return np.concatenate([c, s], axis=1).astype(np.float32)


def decoder_arrays(decoder: Decoder) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{layer: (W (out, in), b (out,))}`` float32 arrays of the decoder."""
    out = {}
    for name in DECODER_LAYERS:
        layer = getattr(decoder, name)
        out[name] = (
            layer.weight.detach().cpu().float().numpy().copy(),
            layer.bias.detach().cpu().float().numpy().copy(),
        )
    return out


def build_network(arch: Architecture, seed: int) -> FabricNetwork:
    """A freshly initialised network (torch's default init, drawn from ``seed`` only)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return FabricNetwork(arch)
