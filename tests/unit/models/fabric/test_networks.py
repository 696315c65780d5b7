"""The encoder-decoder network (:mod:`models.fabric.networks`) and the loss of Eq. 9-11.

Oracles: the ResNet-18 stage layout (shapes, channel counts, parameter count of the
standard width against torchvision's published figure for the same stages); periodic
padding (a tile rolled by a multiple of the network's stride gives the same features);
the closed forms of Eq. 9-11 computed by hand; the inverse of the log map.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from models.fabric.losses import LAMBDA_C, LAMBDA_S, fabric_loss, log_targets
from models.fabric.networks import (
    K_BRDF,
    K_BTDF,
    Architecture,
    ResNet18Trunk,
    build_network,
    components,
    components_numpy,
    resample_map,
)

from .conftest import TINY


def test01_resnet_trunk_shapes_and_size() -> None:
    trunk = ResNet18Trunk(6, 64)
    x = torch.randn(2, 6, 64, 64)
    with torch.no_grad():
        h = torch.nn.functional.relu(trunk.stem_norm(trunk.stem(x)))
        assert h.shape == (2, 64, 32, 32)
        assert trunk.layer3(trunk.layer2(trunk.layer1(h[..., ::2, ::2]))).shape == (2, 256, 4, 4)
        assert trunk(x).shape == (2, 256)
    # torchvision's resnet18 has 11.69 M parameters; its layer4 (8.39 M), fc (0.51 M) and
    # the 3-channel stem (9408) are gone here, the 6-channel stem (18816) added; GroupNorm
    # has BatchNorm's affine parameter count.
    n = sum(p.numel() for p in trunk.parameters())
    assert n == 11_689_512 - 8_393_728 - 513_000 - 9_408 + 18_816


def test02_periodic_padding_makes_features_shift_invariant() -> None:
    torch.manual_seed(0)
    trunk = ResNet18Trunk(6, 16).eval()
    x = torch.randn(1, 6, 64, 64)
    with torch.no_grad():
        a = trunk(x)
        b = trunk(torch.roll(x, shifts=(16, 32), dims=(2, 3)))  # stride 16 after layer3
        c = trunk(torch.roll(x, shifts=(5, 0), dims=(2, 3)))
        y = x.clone()
        y[0, :, 40, 9] += 5.0  # one pixel anywhere reaches the pooled features
        d = trunk(y)
    # float32: rolling reorders GroupNorm's and the pooling's sums (thousands of terms), a
    # few ulps each (measured 1e-6 of this bound); breaking invariance moves > 1e-4 (below).
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert float((a - c).abs().max()) > 1e-4  # not invariant to arbitrary shifts
    assert float((a - d).abs().max()) > 1e-4


def test03_network_shapes() -> None:
    net = build_network(TINY, 0)
    maps = torch.randn(3, 6, TINY.map_resolution, TINY.map_resolution)
    params = torch.rand(3, 5)
    z = net.encoder(maps, params)
    assert z.shape == (3, TINY.latent_dim)
    index = torch.tensor([0, 0, 2, 1, 2])
    raw = net(maps, params, index, torch.rand(5, 8))
    assert raw.shape == (5, 4)
    # Same seed, same weights; other seed, other weights.
    same = build_network(TINY, 0).state_dict()
    other = build_network(TINY, 1).state_dict()
    for k, v in net.state_dict().items():
        assert torch.equal(v, same[k])
    assert not torch.equal(net.decoder.spatial1.weight, other["decoder.spatial1.weight"])


def test04_log_map_inverse_and_hand_values() -> None:
    # Light from below (row 1): no diffuse component (materials.fabric.shading).
    value = torch.tensor([[0.1, 0.2, 0.01, 0.0], [0.0, 0.0, 0.01, 0.5]])
    wi_z = torch.tensor([0.5, -0.5])
    t = log_targets(value, wi_z)
    # Eq. 9: g(x) = ln(k x + 1), k = 100 (BRDF), 1000 (BTDF).
    torch.testing.assert_close(t[0], torch.tensor([0.1, 0.2, math.log(2.0), 0.0]))
    torch.testing.assert_close(t[1], torch.tensor([0.0, 0.0, math.log(11.0), math.log(501.0)]))
    torch.testing.assert_close(components(t, wi_z), value, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(components_numpy(t.numpy(), wi_z.numpy()), value.numpy(), rtol=1e-5)
    assert (K_BRDF, K_BTDF) == (100.0, 1000.0)
    # Negative raw outputs clamp to zero components.
    assert float(components(-torch.ones(1, 4), torch.tensor([1.0])).abs().max()) == 0.0


def test05_loss_eq11_by_hand() -> None:
    raw = torch.zeros(2, 4)
    target = torch.tensor([[1.0, 2.0, 3.0, 4.0], [3.0, 0.0, 1.0, 0.0]])
    # Per-component MSE: (1 + 9) / 2 = 5, 4 / 2 = 2, (9 + 1) / 2 = 5, 16 / 2 = 8.
    parts = fabric_loss(raw, target)
    assert (LAMBDA_S, LAMBDA_C) == (0.4, 0.1)
    assert math.isclose(float(parts.total), 0.1 * (5 + 2) + 0.4 * (5 + 8), rel_tol=1e-6)
    torch.testing.assert_close(parts.per_component, torch.tensor([5.0, 2.0, 5.0, 8.0]))


@pytest.mark.parametrize(("src", "dst"), [(64, 16), (16, 16), (24, 16), (16, 32)])
def test06_resample_map(src: int, dst: int) -> None:
    rng = np.random.default_rng(src + dst)
    img = rng.random((src, src, 3)).astype(np.float32)
    out = resample_map(img, dst)
    assert out.shape == (dst, dst, 3) and out.dtype == np.float32
    # Constant maps stay constant; the mean is kept by box and by periodic linear filters.
    np.testing.assert_allclose(resample_map(np.full((src, src, 3), 0.3), dst), 0.3, rtol=1e-6)
    if src % dst == 0:
        np.testing.assert_allclose(out.mean(), img.mean(), rtol=1e-5)
    if src == 64:
        np.testing.assert_allclose(out[0, 0], img[:4, :4].mean(axis=(0, 1)), rtol=1e-5)


def test07_architecture_roundtrip() -> None:
    a = Architecture(encoder_width=32, decoder_width=48)
    assert Architecture.from_dict(a.as_dict()) == a
