"""The ``glint`` BSDF's layer registry (:func:`~evaluators.render.bsdfs.glint.put_layers`)
does not keep every render's layers alive: a Yan export's lobes are hundreds of MiB, and a
worker renders many materials in one process.

Oracle: Python's own reference counting. A weak reference to each registered layer tells
whether anything still holds it once its scene is dropped and the garbage collected.
"""

from __future__ import annotations

import gc
import types
import weakref
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.glint import (
    GLINT_BSDF_NAME,
    KEPT_LAYERS,
    GlintLayer,
    put_layers,
    register_glint_bsdf,
)
from materials.glints.examples import procedural_example
from materials.glints.lobes import make_lobes
from materials.glints.pndf_drjit import jit_lobes
from materials.microfacet import NAMED_CONDUCTORS

RENDERS = KEPT_LAYERS + 3


def _layer(mi: types.ModuleType, seed: int) -> GlintLayer:
    """A small Yan layer over its own microstructure (seeded: each call's lobes differ)."""
    normals = procedural_example("anisotropic_noise", 8, np.random.default_rng(seed))
    eta, k = NAMED_CONDUCTORS["Al"]
    return GlintLayer(
        method="yan",
        lobes=jit_lobes(mi, make_lobes(normals, rate=1, sigma_r=0.05)),
        maps=None,
        transform=(np.eye(2), np.zeros(2)),
        texel_scale=1.0,
        fresnel=("conductor", eta, k),
        alpha=0.3,
        fallback_texels=2.0,
    )


def _scene(mi: types.ModuleType, key: str) -> Any:
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": {
                "type": "perspective",
                "fov": 40.0,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0.0, 0.0, 3.0], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]
                ),
                "film": {"type": "hdrfilm", "width": 8, "height": 8},
                "sampler": {"type": "independent", "sample_count": 1},
            },
            "quad": {
                "type": "rectangle",
                "bsdf": {"type": GLINT_BSDF_NAME, "layers": key, "texels_per_uv": 8.0},
            },
            "light": {"type": "point", "position": [0.5, 0.5, 2.0], "intensity": 10.0},
        }
    )


def test01_dropped_renders_release_their_layers(mi: types.ModuleType) -> None:
    """After ``RENDERS`` renders of different layers, their scenes dropped, at most
    :data:`KEPT_LAYERS` of the layers are alive (an unbounded registry keeps all of them),
    and a key whose scene is still alive stays valid however many were registered since."""
    register_glint_bsdf(mi)
    alive: list[weakref.ref[GlintLayer]] = []
    held = None
    for i in range(RENDERS):
        layer = _layer(mi, seed=100 + i)
        alive.append(weakref.ref(layer))
        key = put_layers(f"test-registry-{i}", layer)
        del layer
        scene = _scene(mi, key)
        image = np.asarray(mi.render(scene))
        assert np.all(np.isfinite(image)) and image.max() > 0.0
        if i == 0:
            held = scene  # the first scene stays alive through every later registration
        del scene, image
    gc.collect()
    kept = [i for i, ref in enumerate(alive) if ref() is not None]
    assert 0 in kept  # held by its live scene's BSDF
    assert len([i for i in kept if i != 0]) <= KEPT_LAYERS, kept
    _scene(mi, "test-registry-0")  # its key is still registered
    del held
    gc.collect()
    assert alive[0]() is None
    with pytest.raises(RuntimeError, match="no prepared layers"):  # load_dict wraps it
        _scene(mi, "test-registry-0")
