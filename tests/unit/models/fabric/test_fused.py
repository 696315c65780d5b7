"""Rendering-side decoder (:mod:`models.fabric.fused`): fused Dr.Jit == numpy == torch.

Oracles: the torch decoder of :mod:`models.fabric.networks` (the trained module itself);
the numpy reference decoder, which shares only the layer arrays with the fused kernel; the
``generate.fabric`` EXR maps (:func:`generators.fabric.preview.map_images`) for
``material_maps``; the torch encoder for ``encode_material``.
"""

from __future__ import annotations

import json
import types

import numpy as np
import pytest
import torch

from generators.fabric.preview import map_images
from materials.fabric.params import FabricParams
from models.fabric.fused import (
    decoder_drjit,
    decoder_numpy,
    encode_material,
    load_fabric_model,
    material_maps,
)
from models.fabric.networks import build_network, components
from models.fabric.portable import checkpoint_bytes, to_portable
from storage.formats.exr import read_exr

from .conftest import TINY


def queries(n: int, seed: int) -> dict[str, np.ndarray]:
    """BRDF and BTDF queries, centres outside the tile and sizes beyond 5 included."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    wi = v / np.linalg.norm(v, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.01
    wo = v / np.linalg.norm(v, axis=1, keepdims=True)
    return {
        "cx": rng.uniform(-1.5, 2.5, n).astype(np.float32),
        "cy": rng.uniform(0, 1, n).astype(np.float32),
        "size": rng.uniform(0, 6, n).astype(np.float32),
        "wi": wi.astype(np.float32),
        "wo": wo.astype(np.float32),
    }


@pytest.fixture(scope="module")
def trained_like() -> tuple[torch.nn.Module, bytes, bytes, np.ndarray]:
    """A random network with its outputs pushed into the positive range (so that C and S
    are not all clamped), its model.json and model.pt bytes, and two latents."""
    net = build_network(TINY, 7).eval()
    with torch.no_grad():
        net.decoder.angular5.bias.copy_(torch.tensor([0.2, 0.1, 1.0, 0.5]))
    latents = np.random.default_rng(3).normal(size=(2, TINY.latent_dim)).astype(np.float32)
    rec = {"alpha": [0.3, 0.4], "beta": [0.5, 0.6], "w": 0.7}
    doc = to_portable(net, ["a", "b"], ["plain", "plain"], [rec, rec], latents)
    text = json.dumps(doc, sort_keys=True).encode()
    return net, text, checkpoint_bytes(net, ["a", "b"], [rec, rec], latents), latents


def torch_raw(net: torch.nn.Module, z: np.ndarray, q: dict[str, np.ndarray]) -> np.ndarray:
    x = np.concatenate([q["cx"][:, None], q["cy"][:, None], q["size"][:, None], q["wi"],
                        q["wo"][:, :2]], axis=1)  # fmt: skip
    with torch.no_grad():
        zz = torch.from_numpy(z)[None].expand(len(x), -1)
        return net.decoder(zz, torch.from_numpy(x.astype(np.float32))).numpy()


def test01_numpy_decoder_matches_torch(trained_like: tuple) -> None:
    net, text, ckpt, latents = trained_like
    q = queries(3000, 1)
    for data in (text, ckpt):
        model = load_fabric_model(data)
        for i, name in enumerate(("a", "b")):
            raw = decoder_numpy(model, name, **q, raw=True)
            ref = torch_raw(net, latents[i], q)
            np.testing.assert_allclose(raw, ref, rtol=1e-5, atol=1e-6)
            comp = decoder_numpy(model, latents[i], **q)
            want = components(torch.from_numpy(ref), torch.from_numpy(q["wi"][:, 2])).numpy()
            np.testing.assert_allclose(comp, want, rtol=1e-5, atol=1e-7)
            assert np.all(comp[:, 2:] > 0)  # the pushed biases keep S in range


def test02_fused_decoder_matches_numpy(mi: types.ModuleType, trained_like: tuple) -> None:
    import drjit as dr

    _, text, _, latents = trained_like
    model = load_fabric_model(text)
    q = queries(4096, 2)
    args = [q["cx"], q["cy"], q["size"], *q["wi"].T, *q["wo"][:, :2].T]
    for raw in (True, False):
        ref = decoder_numpy(model, latents[1], **q, raw=raw)
        f = decoder_drjit(model, latents[1], mi.Float, raw=raw)
        out = f(*(mi.Float(a) for a in args))
        dr.eval(out)
        got = np.stack([o.numpy() for o in out], axis=1)
        err = np.abs(got - ref) / np.maximum(np.abs(ref), 1e-3 if not raw else 1.0)
        print(f"\nraw={raw}: max relative error {err.max():.2e}")
        assert err.max() < 1e-5
    # The latent baked into the kernel as literals (one kernel per material).
    ref = decoder_numpy(model, latents[0], **q)
    out = decoder_drjit(model, latents[0], mi.Float, bake_latent=True)(*(mi.Float(a) for a in args))
    got = np.stack([o.numpy() for o in out], axis=1)
    assert (np.abs(got - ref) / np.maximum(np.abs(ref), 1e-3)).max() < 1e-5
    # numpy inputs are converted to the given float type.
    out = decoder_drjit(model, "b", mi.Float)(*args)
    assert type(out[0]) is mi.Float and dr.width(out[0]) == 4096


def test03_material_maps_are_the_dataset_maps() -> None:
    params = FabricParams("satin_5x5", psi_deg=(20, -10), u_max_deg=(25, 35), beta=(0.7, 0.4))
    normal, orientation = material_maps(params, 24)
    exr_n, exr_t = map_images(params, 24)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        for data, arr in ((exr_n, normal), (exr_t, orientation)):
            p = Path(d) / "m.exr"
            p.write_bytes(data)
            np.testing.assert_array_equal(read_exr(p), arr)
    assert normal.shape == (24, 24, 3) and normal.dtype == np.float32


def test04_encode_material_matches_the_torch_encoder(trained_like: tuple) -> None:
    net, text, ckpt, _ = trained_like
    params = FabricParams("twill_3x3", alpha=(0.3, 0.4), beta=(0.5, 0.6), w=0.7)
    n, t = material_maps(params, 64)  # resampled 64 -> 16 by box filtering
    z = encode_material(load_fabric_model(ckpt), params, n, t)
    assert z.shape == (TINY.latent_dim,) and z.dtype == np.float32
    from models.fabric.networks import map_tensor, param_vector

    with torch.no_grad():
        ref = net.encoder(
            torch.from_numpy(map_tensor(n, t, TINY.map_resolution))[None],
            torch.from_numpy(param_vector({"alpha": [0.3, 0.4], "beta": [0.5, 0.6], "w": 0.7}))[
                None
            ],
        )[0].numpy()
    np.testing.assert_array_equal(z, ref)
    with pytest.raises(ValueError, match="model.pt"):
        encode_material(load_fabric_model(text), params, n, t)


def test05_load_rejects_other_data() -> None:
    with pytest.raises(ValueError):
        load_fabric_model(b'{"format": "matforge.brdf-model/1"}')
    with pytest.raises(ValueError):
        load_fabric_model(b"\x00not a checkpoint")


def test06_materials_share_one_kernel_unless_baked(
    mi: types.ModuleType, trained_like: tuple
) -> None:
    """Opaque latents: the second material's kernel has the first one's hash (Dr.Jit kernel
    history); baked latents give a new kernel per material."""
    import drjit as dr

    _, text, _, latents = trained_like
    model = load_fabric_model(text)
    q = queries(64, 4)
    args = [mi.Float(a) for a in (q["cx"], q["cy"], q["size"], *q["wi"].T, *q["wo"][:, :2].T)]
    dr.eval(*args)
    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        hashes = {}
        for bake in (False, True):
            seen = []
            for z in latents:
                dr.kernel_history_clear()
                dr.eval(*decoder_drjit(model, z, mi.Float, bake_latent=bake)(*args))
                seen.append(
                    [k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
                )
            hashes[bake] = seen
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)
    assert hashes[False][0] == hashes[False][1]
    assert hashes[True][0] != hashes[True][1]
