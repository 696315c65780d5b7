"""Fixtures of the fabric-model unit tests: a tiny architecture and synthetic materials."""

from __future__ import annotations

import numpy as np
import pytest

from materials.fabric.params import FabricParams
from models.fabric.data import MaterialData, holdout_split
from models.fabric.fused import material_maps
from models.fabric.networks import Architecture, map_tensor, param_vector

#: Small enough for a training step in a few milliseconds.
TINY = Architecture(encoder_width=16, map_resolution=16, decoder_width=16)


def synthetic_material(name: str, pattern: str, seed: int, n: int = 256) -> MaterialData:
    """A material with real maps (``rasterize``) and smooth synthetic targets.

    Targets: ``C = 0.2 wi.z+ (1 + 0.5 sin 2 pi cx)`` per yarn, ``S = 0.05 (1 + cos(2 pi cy))
    wo.z`` scaled per yarn; enough structure to learn, cheap to make.
    """
    rng = np.random.default_rng(seed)
    params = FabricParams(pattern, alpha=(0.3, 0.5), beta=(0.6, 0.8), w=0.7)
    normal, orientation = material_maps(params, 32)
    v = rng.normal(size=(n, 3))
    wi = v / np.linalg.norm(v, axis=1, keepdims=True)
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    wo = v / np.linalg.norm(v, axis=1, keepdims=True)
    cx, cy, size = rng.random(n), rng.random(n), rng.random(n) * 5
    query = np.concatenate([cx[:, None], cy[:, None], size[:, None], wi, wo[:, :2]], 1)
    c = 0.2 * np.maximum(wi[:, 2], 0) * (1 + 0.5 * np.sin(2 * np.pi * cx))
    s = 0.05 * (1 + np.cos(2 * np.pi * cy)) * wo[:, 2]
    value = np.stack([c, 0.5 * c, s, 0.3 * s], axis=1)
    record = {"alpha": [0.3, 0.5], "beta": [0.6, 0.8], "w": 0.7, "kd_warp": [0.5] * 3,
              "kd_weft": [0.4] * 3, "ks_warp": [0.3] * 3, "ks_weft": [0.2] * 3}  # fmt: skip
    train, test = holdout_split(name, n, 0.25)
    return MaterialData(
        name=name,
        pattern=pattern,
        record=record,
        maps=map_tensor(normal, orientation, TINY.map_resolution),
        params=param_vector(record),
        query=query.astype(np.float32),
        value=value.astype(np.float32),
        train=train,
        test=test,
    )


@pytest.fixture(scope="session")
def synthetic_materials() -> list[MaterialData]:
    return [
        synthetic_material("plain-a", "plain", 1),
        synthetic_material("twill-b", "twill_3x3", 2),
    ]
