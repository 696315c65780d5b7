"""BTF networks, their portable form and the fused Dr.Jit evaluation, against each other and
against identities the paper implies:

- the bilinear periodic texture lookup returns a texel at its centre and the mean of two
  neighbours half-way between them (and wraps);
- the portable numpy evaluator equals the torch network at texel centres, and the fused
  Dr.Jit texture pass equals the numpy one (float32 summation order only);
- the 2 x 2 amortised student (coarse MLP once per block) equals the per-texel evaluation
  wherever the coarse inputs coincide (directions constant within each block);
- the storage of Table 1 at 400 x 400 texels: NeuMIP 4.48 MB (7 channels + a 6.6 KB MLP),
  the student 6.24 MB (8 + 7/4 channels + ~1.5 KB);
- the fused Lafortune evaluation equals :func:`materials.btf.lafortune.lafortune_eval`.

Tolerances (``rtol`` 1e-5 to 2e-5): torch, numpy/BLAS and Dr.Jit sum the same small
float32 MLPs in different orders, a few ulps (1.2e-7) of the terms per layer; measured at
most a tenth of each tolerance here (AMD EPYC). A texel or direction mixed up moves values
by O(0.1).
"""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch

from materials.btf.directions import to_vector
from materials.btf.lafortune import PARAMS_PER_TEXEL, initial_params, lafortune_eval
from models.btf.fused import FusedBtf
from models.btf.networks import Architecture, build_network, sample_texture, slice_forward
from models.btf.portable import (
    PortableBtf,
    model_document,
    network_layers,
    network_textures,
    read_model,
)


def _portable(net: torch.nn.Module) -> PortableBtf:
    tex = network_textures(net)
    doc = model_document(net.arch.model, net.arch.as_dict(), network_layers(net), tex, {})
    return read_model(doc, tex)


def _net(model: str, width: int, res: tuple[int, int] = (8, 6), seed: int = 0) -> torch.nn.Module:
    net = build_network(Architecture(model=model, width=width, resolution=res), seed)
    with torch.no_grad():  # spread the textures so the MLPs see varied inputs
        for p in net.parameters():
            if p.dim() == 3:
                p.mul_(10.0)
    return net.eval()


def test01_texture_lookup_identities() -> None:
    tex = torch.arange(2 * 3 * 4, dtype=torch.float32).reshape(2, 3, 4)
    h, w = 3, 4
    centre = torch.tensor([[(1 + 0.5) / w, (2 + 0.5) / h]])
    assert torch.equal(sample_texture(tex, centre)[0], tex[:, 2, 1])
    mid = torch.tensor([[(1 + 1.0) / w, (2 + 0.5) / h]])  # half-way between columns 1 and 2
    assert torch.allclose(sample_texture(tex, mid)[0], 0.5 * (tex[:, 2, 1] + tex[:, 2, 2]))
    wrap = torch.tensor([[0.0, (0 + 0.5) / h]])  # half-way between the last and first column
    assert torch.allclose(sample_texture(tex, wrap)[0], 0.5 * (tex[:, 0, 3] + tex[:, 0, 0]))


@pytest.mark.parametrize(("model", "width"), [("neumip", 25), ("neumip", 8), ("c2f", 8)])
def test02_portable_equals_torch(model: str, width: int) -> None:
    net = _net(model, width)
    port = _portable(net)
    for wi, wo in ((to_vector(30, 40), to_vector(60, 200)), (to_vector(0, 0), to_vector(75, 10))):
        with torch.no_grad():
            ref, _ = slice_forward(net, torch.tensor(wi, dtype=torch.float32),
                                   torch.tensor(wo, dtype=torch.float32))  # fmt: skip
        ref = np.maximum(ref.numpy(), 0.0).reshape(8, 6, 3)
        np.testing.assert_allclose(port.slice(wi, wo), ref, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(("model", "width"), [("neumip", 25), ("c2f", 8)])
def test03_fused_equals_numpy(mi: types.ModuleType, model: str, width: int) -> None:
    port = _portable(_net(model, width))
    fused = FusedBtf(port, mi)
    wi, wo = to_vector(45, 30), to_vector(20, 250)
    np.testing.assert_allclose(fused.slice(wi, wo), port.slice(wi, wo), rtol=1e-5, atol=1e-6)
    # and at arbitrary uv: the texel centres give the slice again
    h, w = port.resolution
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = mi.Point2f(mi.Float(((ii + 0.5) / w).ravel()), mi.Float(((jj + 0.5) / h).ravel()))
    n = h * w
    wiv = mi.Vector3f(*(mi.Float(np.full(n, c, np.float32)) for c in wi))
    wov = mi.Vector3f(*(mi.Float(np.full(n, c, np.float32)) for c in wo))
    at_uv = np.asarray(fused.eval(uv, wiv, wov), np.float32).T.reshape(h, w, 3)
    np.testing.assert_allclose(at_uv, port.slice(wi, wo), rtol=1e-5, atol=1e-6)


def test04_amortised_student_equals_per_texel(mi: types.ModuleType) -> None:
    """Directions differ between 2 x 2 blocks but not within one: the amortised pass (M_c
    once per block) must equal evaluating every texel on its own."""
    port = _portable(_net("c2f", 8, res=(8, 8), seed=3))
    fused = FusedBtf(port, mi)
    h = w = 8
    rng = np.random.default_rng(0)
    block_wi = to_vector(rng.uniform(0, 70, 16), rng.uniform(0, 360, 16)).reshape(4, 4, 3)
    block_wo = to_vector(rng.uniform(0, 70, 16), rng.uniform(0, 360, 16)).reshape(4, 4, 3)
    wi = np.repeat(np.repeat(block_wi, 2, axis=0), 2, axis=1).reshape(-1, 3)
    wo = np.repeat(np.repeat(block_wo, 2, axis=0), 2, axis=1).reshape(-1, 3)
    vec = lambda a: mi.Vector3f(*(mi.Float(a[:, k].astype(np.float32)) for k in range(3)))  # noqa: E731
    assert fused.lanes() == 16
    np.testing.assert_allclose(fused.lane_centres()[5], [(1 + 0.5) / 4, (1 + 0.5) / 4])
    amortised = fused.assemble(
        fused.shade_texture(vec(block_wi.reshape(-1, 3)), vec(block_wo.reshape(-1, 3)))
    )
    jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    uv = mi.Point2f(mi.Float(((ii + 0.5) / w).ravel()), mi.Float(((jj + 0.5) / h).ravel()))
    per_texel = np.asarray(fused.eval(uv, vec(wi), vec(wo)), np.float32).T.reshape(h, w, 3)
    np.testing.assert_allclose(amortised, per_texel, rtol=1e-6, atol=1e-7)
    # and per texel in numpy, each texel's own slice evaluation at its block's directions
    for j, i in ((0, 0), (3, 5), (7, 7)):
        ref = port.slice(wi[j * w + i], wo[j * w + i])[j, i]
        np.testing.assert_allclose(amortised[j, i], ref, rtol=1e-5, atol=1e-6)


def test05_storage_of_table1() -> None:
    neumip = _portable(build_network(Architecture("neumip", 25, (400, 400)), 0))
    c2f = _portable(build_network(Architecture("c2f", 8, (400, 400)), 0))
    s_n, s_c = neumip.doc["storage"], c2f.doc["storage"]
    assert s_n["texture_bytes"] == 400 * 400 * 7 * 4
    assert s_n["total_bytes"] / 1e6 == pytest.approx(4.48, abs=0.01)
    assert 6.0e3 < s_n["network_bytes"] < 7.0e3  # the paper: 6.6 KB
    assert s_c["texture_bytes"] == 400 * 400 * 8 * 4 + 200 * 200 * 7 * 4
    assert s_c["total_bytes"] / 1e6 == pytest.approx(6.24, abs=0.01)
    assert 1.2e3 < s_c["network_bytes"] < 1.7e3  # the paper: 1.6 KB


def test06_fused_lafortune_equals_numpy(mi: types.ModuleType) -> None:
    rng = np.random.default_rng(1)
    h, w = 4, 5
    p = initial_params(rng.uniform(0.05, 0.3, (h * w, 3)))
    p[:, 3:] += rng.normal(0, 0.05, p[:, 3:].shape)  # perturb lobes
    tex = {"params": p.reshape(h, w, PARAMS_PER_TEXEL).astype(np.float32)}
    arch = {"model": "lafortune", "width": 0, "resolution": [h, w]}
    port = read_model(model_document("lafortune", arch, {}, tex, {}), tex)
    wi, wo = to_vector(35, 10), to_vector(50, 170)
    expect = lafortune_eval(tex["params"].reshape(h * w, -1).astype(np.float64),
                            wi[None], wo[None])[:, 0].reshape(h, w, 3)  # fmt: skip
    np.testing.assert_allclose(port.slice(wi, wo), np.maximum(expect, 0), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(FusedBtf(port, mi).slice(wi, wo), np.maximum(expect, 0),
                               rtol=2e-5, atol=1e-7)  # fmt: skip


def test07_half_precision_textures(mi: types.ModuleType) -> None:
    """float16 texture storage (arithmetic stays float32: storage only, not the paper's
    half-precision inference) changes the result only by
    the textures' rounding: the same model with its textures rounded to float16 in numpy."""
    port = _portable(_net("c2f", 8, seed=5))
    rounded = {k: v.astype(np.float16).astype(np.float32) for k, v in port.textures.items()}
    ref = read_model(port.doc, rounded)
    wi, wo = to_vector(25, 80), to_vector(55, 300)
    np.testing.assert_allclose(FusedBtf(port, mi, half=True).slice(wi, wo), ref.slice(wi, wo),
                               rtol=1e-5, atol=1e-6)  # fmt: skip


def test_network_sizes_against_the_paper() -> None:
    """The networks' own sizes, counted layer by layer by hand (float32): the student
    (16 -> 8, 8 -> 8, 16 -> 8, 8 -> 3, weights and biases) 371 floats = 1,484 B against
    Table 1's 1.6 KB (25-40 floats fewer: not explained by the paper's text); NeuMIP-25
    (11 -> 25, 25 -> 25 twice, 25 -> 3) 1,678 floats = 6,712 B = 6.55 KiB, the paper's
    6.6 KB. The 400^2 totals (6.24 MB, 4.49 MB) match Table 1 because the texture
    channels (7 coarse + 8 fine; 7) were chosen so that they do: by construction."""
    from models.btf.networks import Architecture, build_network

    c2f = build_network(Architecture("c2f", 8, (400, 400)), 0)
    neumip = build_network(Architecture("neumip", 25, (400, 400)), 0)
    hand_c2f = ((7 + 9) * 8 + 8) + (8 * 8 + 8) + ((8 + 8) * 8 + 8) + (8 * 3 + 3)
    hand_neumip = (11 * 25 + 25) + 2 * (25 * 25 + 25) + (25 * 3 + 3)
    assert (hand_c2f, hand_neumip) == (371, 1678)
    assert c2f.network_bytes() == 4 * hand_c2f == 1484  # type: ignore[operator]
    assert neumip.network_bytes() == 4 * hand_neumip == 6712  # type: ignore[operator]
    assert c2f.texture_bytes() == (7 * 200 * 200 + 8 * 400 * 400) * 4 == 6_240_000  # type: ignore[operator]
    assert neumip.texture_bytes() == 7 * 400 * 400 * 4 == 4_480_000  # type: ignore[operator]
