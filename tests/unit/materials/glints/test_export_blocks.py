"""``export_normal_map`` evaluates in blocks (a stochastic surface's owner test is linear in
the instances it is given): the blocks must give the same bytes as one call over the whole
map. Reference: the same export with one block covering everything."""

from __future__ import annotations

import numpy as np
import pytest

import materials.glints.surface as surface_mod
from materials.glints.examples import procedural_example
from materials.glints.surface import Distribution, Surface, export_normal_map


@pytest.mark.parametrize("kind", ["stochastic", "tiled"])
def test01_blocks_give_the_whole_maps_bytes(kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    example = procedural_example("scratches", 16, np.random.default_rng(3))
    dist = Distribution(kind=kind, scale_range=(0.8, 1.25), seed=1)
    surf = Surface(example, dist)
    # 70 x 2 = 140 export texels: blocks of 32 leave a partial block at each edge.
    monkeypatch.setattr(surface_mod, "EXPORT_BLOCK", 32)
    blocked = export_normal_map(surf, 70, oversample=2, origin=(5.0, -3.0))
    monkeypatch.setattr(surface_mod, "EXPORT_BLOCK", 10**6)
    whole = export_normal_map(surf, 70, oversample=2, origin=(5.0, -3.0))
    assert blocked.shape == (140, 140, 3)
    np.testing.assert_array_equal(blocked, whole)
    assert np.abs(blocked[..., :2]).max() > 0.05  # not a flat (empty) map
