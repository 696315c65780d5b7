"""Neural BTF models: neural textures, the modified NeuMIP and the coarse-to-fine student.

**Neural textures.** A texture is a ``(C, H, W)`` grid of latent features over the patch
``[0, 1)^2``, texel ``[j, i]`` centred at ``((i + 0.5) / W, (j + 0.5) / H)``, looked up
bilinearly and periodically (the patch tiles). Training samples each texel's texture at a
uniformly jittered point within its texel: the paper's "stratified sampling of the neural
textures to avoid the discrete artifact" (Sec. 4.4), which makes the texture meaningful
between centres.

**Modified NeuMIP** (Sec. 5.2): Kuznetsov et al.'s NeuMIP without its offset module and
with one neural texture at the finest level (no pyramid). Inputs: 7 texture channels and
the directions' projections ``wi.xy, wo.xy``; three hidden ReLU layers of ``width``
(25; 128 for the "NeuMIP Max" teacher; 8 for the same-capacity variant of Fig. 8); linear
RGB out. At 400^2 texels it stores 7 x 4 bytes per texel plus 1,678 weights (6,712 B; the
paper gives 6.6 KB): 4.49 MB, the 4.48 MB of the paper's Table 1.

**Coarse-to-fine student** (Sec. 4.1): a coarse texture ``U_c`` of 7 channels at half
resolution (one texel per 2 x 2 block, centred on the block's centre ``u_c``) and a fine
texture ``U_f`` of 8 channels at full resolution: 6.24 MB at 400^2, Table 1's figure. That
match is by construction: the paper gives the totals, not the channel counts, and 7 and 8
were solved from Table 1's 6.24 MB (and NeuMIP's 7 from its 4.48 MB). The networks' own
sizes are an independent check: NeuMIP-25's 6,712 B is the paper's 6.6 KB (6.55 KiB); the
student's 371 weights, 1,484 B (1.45 KiB), are 25-40 floats under the paper's 1.6 KB, a
difference its text does not explain (``tests/unit/models/btf/test_btf_networks.py``).

- Eq. 3: ``z_c = M_c(wi, wo, h, U_c(u_c))``, ``M_c``: 16 -> 8 -> 8, ReLU after both;
- Eq. 4: ``BTF(u_k) = M_f(z_c, U_f(u_k))``, ``M_f``: 16 -> 8 -> 3, ReLU, linear out;

so each block runs ``M_c`` once and ``M_f`` four times. ``h`` is the normalised half vector;
``wi``, ``wo`` are full 3-vectors, taken at the block centre (the same for all four texels,
Sec. 4.1; in a BTF slice they are the same everywhere anyway).

**Distillation taps** (Eq. 5): each network returns its hidden activations; the student's
``z_c`` and its fine hidden layer are matched to the teacher's second and third hidden
layers through learned linear maps ``T_1``, ``T_2`` (teacher width -> 8).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

#: Model names of ``train.btf`` that are networks.
NETWORK_MODELS = ("neumip", "neumip_max", "c2f")
#: NeuMIP's texture channels; the student's coarse and fine channels.
NEUMIP_CHANNELS, COARSE_CHANNELS, FINE_CHANNELS = 7, 7, 8
#: The student's MLP width (Sec. 4.1) and NeuMIP's hidden layers.
STUDENT_WIDTH, NEUMIP_HIDDEN = 8, 3
#: Initial spread of neural texture values.
TEXTURE_INIT = 0.1


@dataclass(frozen=True)
class Architecture:
    """A network's shape: ``model`` (``neumip`` or ``c2f``), MLP ``width``, texture
    ``resolution`` ``(H, W)`` of the BTF, texture channels."""

    model: str
    width: int
    resolution: tuple[int, int]
    channels: int = NEUMIP_CHANNELS
    coarse_channels: int = COARSE_CHANNELS
    fine_channels: int = FINE_CHANNELS

    def as_dict(self) -> dict[str, object]:
        d = asdict(self)
        d["resolution"] = list(self.resolution)
        return d


def sample_texture(tex: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Bilinear, periodic lookup of ``tex`` ``(C, H, W)`` at ``u`` ``(N, 2)`` (x, y in patch
    units; texel centres at ``(i + 0.5) / W``) -> ``(N, C)``."""
    c, h, w = tex.shape
    x = u[:, 0] * w - 0.5
    y = u[:, 1] * h - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    i0 = torch.remainder(x0.long(), w)
    j0 = torch.remainder(y0.long(), h)
    i1, j1 = torch.remainder(i0 + 1, w), torch.remainder(j0 + 1, h)
    flat = tex.reshape(c, h * w).t()
    a, b = flat[j0 * w + i0], flat[j0 * w + i1]
    cc, d = flat[j1 * w + i0], flat[j1 * w + i1]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (cc * (1 - fx) + d * fx) * fy


def texel_grid(
    h: int, w: int, generator: torch.Generator | None = None, device: torch.device | None = None
) -> torch.Tensor:
    """``(H * W, 2)`` points, one per texel in row-major order: the centres, or (with a
    ``generator``) uniform points within each texel (stratified sampling). The points are
    drawn on the CPU (a CPU ``generator``: the same stream whatever the device) and moved
    to ``device``."""
    jj, ii = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    if generator is None:
        ox = oy = torch.full((h * w,), 0.5)
    else:
        ox = torch.rand(h * w, generator=generator)
        oy = torch.rand(h * w, generator=generator)
    grid = torch.stack([(ii.reshape(-1) + ox) / w, (jj.reshape(-1) + oy) / h], dim=1)
    return grid if device is None else grid.to(device)


def _texture(c: int, h: int, w: int, generator: torch.Generator) -> nn.Parameter:
    init = (torch.rand(c, h, w, generator=generator) * 2 - 1) * TEXTURE_INIT
    return nn.Parameter(init)


def _linear(n_in: int, n_out: int, generator: torch.Generator) -> nn.Linear:
    layer = nn.Linear(n_in, n_out)
    bound = 1.0 / math.sqrt(n_in)  # torch's default init, drawn from our generator
    with torch.no_grad():
        layer.weight.uniform_(-bound, bound, generator=generator)
        layer.bias.uniform_(-bound, bound, generator=generator)
    return layer


class NeuMIP(nn.Module):
    """The modified NeuMIP (see the module docstring)."""

    def __init__(self, arch: Architecture, generator: torch.Generator) -> None:
        super().__init__()
        self.arch = arch
        h, w = arch.resolution
        self.texture = _texture(arch.channels, h, w, generator)
        dims = [arch.channels + 4] + [arch.width] * NEUMIP_HIDDEN
        self.hidden = nn.ModuleList(
            _linear(a, b, generator) for a, b in zip(dims[:-1], dims[1:], strict=True)
        )
        self.out = _linear(arch.width, 3, generator)

    def forward(
        self, u: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor
    ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """``u`` ``(N, 2)``, ``wi``/``wo`` ``(3,)`` or ``(N, 3)`` -> RGB ``(N, 3)`` and the
        hidden activations."""
        n = u.shape[0]
        feat = sample_texture(self.texture, u)
        ang = torch.cat([wi[..., :2].expand(n, 2), wo[..., :2].expand(n, 2)], dim=1)
        x = torch.cat([feat, ang], dim=1)
        hidden = []
        for layer in self.hidden:
            x = torch.relu(layer(x))
            hidden.append(x)
        return self.out(x), hidden

    def texture_bytes(self) -> int:
        return int(self.texture.numel()) * 4

    def network_bytes(self) -> int:
        return sum(int(p.numel()) for n, p in self.named_parameters() if n != "texture") * 4


def half_vector(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """Normalised ``wi + wo`` (``(..., 3)``)."""
    h = wi + wo
    return h / torch.clamp(torch.linalg.norm(h, dim=-1, keepdim=True), min=1e-8)


class CoarseToFine(nn.Module):
    """The coarse-to-fine student (see the module docstring); needs even ``H`` and ``W``."""

    def __init__(self, arch: Architecture, generator: torch.Generator) -> None:
        super().__init__()
        h, w = arch.resolution
        if h % 2 or w % 2:
            raise ValueError(f"the coarse-to-fine model needs an even resolution, got {h}x{w}")
        self.arch = arch
        self.coarse_texture = _texture(arch.coarse_channels, h // 2, w // 2, generator)
        self.fine_texture = _texture(arch.fine_channels, h, w, generator)
        width = arch.width
        self.coarse1 = _linear(arch.coarse_channels + 9, width, generator)
        self.coarse2 = _linear(width, width, generator)
        self.fine1 = _linear(width + arch.fine_channels, width, generator)
        self.fine2 = _linear(width, 3, generator)

    def coarse(
        self, uc: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Eq. 3 at block centres ``uc`` ``(B, 2)``: ``z_c`` ``(B, width)`` and the first
        hidden layer."""
        b = uc.shape[0]
        ang = torch.cat([wi.expand(b, 3), wo.expand(b, 3), half_vector(wi, wo).expand(b, 3)], dim=1)
        x = torch.cat([sample_texture(self.coarse_texture, uc), ang], dim=1)
        h1 = torch.relu(self.coarse1(x))
        return torch.relu(self.coarse2(h1)), h1

    def fine(self, zc: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Eq. 4: RGB at texel points ``u`` ``(N, 2)`` from their blocks' ``z_c`` ``(N, w)``;
        and the fine hidden layer."""
        x = torch.cat([zc, sample_texture(self.fine_texture, u)], dim=1)
        h = torch.relu(self.fine1(x))
        return self.fine2(h), h

    def forward_slice(
        self,
        wi: torch.Tensor,
        wo: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """A whole slice, texels in row-major order ``(H * W, 3)``; with a ``generator``
        the textures are sampled at jittered points (training). Returns the RGB and the
        distillation taps ``[z_c per texel, fine hidden]``."""
        h, w = self.arch.resolution
        dev = self.fine_texture.device
        uc = texel_grid(h // 2, w // 2, generator, dev)
        zc, _ = self.coarse(uc, wi, wo)
        u = texel_grid(h, w, generator, dev)
        jj, ii = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        block = ((jj // 2) * (w // 2) + ii // 2).reshape(-1).to(dev)
        z = zc[block]
        rgb, hidden = self.fine(z, u)
        return rgb, [z, hidden]

    def texture_bytes(self) -> int:
        return (int(self.coarse_texture.numel()) + int(self.fine_texture.numel())) * 4

    def network_bytes(self) -> int:
        tex = {"coarse_texture", "fine_texture"}
        return sum(int(p.numel()) for n, p in self.named_parameters() if n not in tex) * 4


def slice_forward(
    net: nn.Module, wi: torch.Tensor, wo: torch.Tensor, generator: torch.Generator | None = None
) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Any network on a whole slice (row-major texels): RGB ``(H * W, 3)`` and taps (for
    NeuMIP its hidden layers; for the student ``[z_c, fine hidden]``)."""
    if isinstance(net, CoarseToFine):
        return net.forward_slice(wi, wo, generator)
    assert isinstance(net, NeuMIP)
    h, w = net.arch.resolution
    return net(texel_grid(h, w, generator, net.texture.device), wi, wo)


def build_network(arch: Architecture, seed: int) -> nn.Module:
    """A freshly initialised network of ``arch`` (weights from ``seed``)."""
    gen = torch.Generator().manual_seed(int(seed))
    if arch.model == "c2f":
        return CoarseToFine(arch, gen)
    if arch.model == "neumip":
        return NeuMIP(arch, gen)
    raise ValueError(f"unknown network model {arch.model!r}")
