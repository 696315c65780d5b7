"""``yan_eval: "hierarchical"`` in the glint source and BSDF: the layer carries the
hierarchy, evaluates the same P-NDF as the brute-force layer of the same export, and its
memory adds the hierarchy's bytes.

Oracle: the brute-force layer (``yan_eval: "brute_force"``). Tolerance as in
``tests/unit/materials/glints/test_pndf_yan_hier.py``: the truncation bound at
``k = 5`` (``exp(-12.5)`` of the box's peaks, below 1e-3 here) plus 1e-4 of the value
for float32 sums in a different order.
"""

from __future__ import annotations

import types

import numpy as np

from evaluators.render.bsdfs.glint import layer_pndf
from evaluators.render.sources.glint import layer_bytes, make_layer
from materials.glints.examples import procedural_example
from materials.glints.lobes import LOBE_BYTES, make_lobes
from materials.glints.pndf_drjit import Sym2
from materials.glints.pndf_yan_hier import bounds_bytes
from materials.glints.surface import Distribution, Surface


def test01_hierarchical_layer_equals_brute_force(mi: types.ModuleType) -> None:
    normals = procedural_example("isotropic_noise", 16, np.random.default_rng(2))
    data = {"lobes": make_lobes(normals, rate=2, sigma_r=0.02)}
    surface = Surface(normals, Distribution())
    common = {"texels_per_uv": 40.0, "oversample": 2, "field": "material.glint", "yan_rate": 1}
    fresnel = ("conductor", (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))
    brute = make_layer(mi, data, surface, "yan", fresnel, **common)  # type: ignore[arg-type]
    hier = make_layer(
        mi,
        data,
        surface,
        "yan",
        fresnel,
        yan_eval="hierarchical",
        **common,  # type: ignore[arg-type]
    )
    assert brute.bounds is None and hier.bounds is not None
    assert hier.bounds.n == 80  # the export: 40 texels at 2 per texel
    rng = np.random.default_rng(5)
    m = 512
    q = rng.normal(0.0, 0.2, (m, 2)).astype(np.float32)
    c = rng.uniform(0.0, 40.0, (m, 2)).astype(np.float32)
    sig = rng.uniform(0.3, 4.0, m).astype(np.float32)
    cov = Sym2(mi.Float(sig * sig), mi.Float(0.2 * sig * sig), mi.Float(0.7 * sig * sig))
    args = ((mi.Float(c[:, 0]), mi.Float(c[:, 1])), cov, (mi.Float(q[:, 0]), mi.Float(q[:, 1])))
    want = np.asarray(layer_pndf(mi, brute, *args, mi.Bool(True)).numpy())
    got = np.asarray(layer_pndf(mi, hier, *args, mi.Bool(True)).numpy())
    assert want.max() > 1.0
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)


def test02_memory_adds_the_hierarchy() -> None:
    brute = layer_bytes("yan", tiny_bytes=None, texels_per_uv=100.0, oversample=2, yan_rate=2)
    hier = layer_bytes(
        "yan", tiny_bytes=None, texels_per_uv=100.0, oversample=2, yan_rate=2,
        yan_eval="hierarchical",
    )  # fmt: skip
    assert brute == (400 * 400) * LOBE_BYTES
    assert hier == brute + bounds_bytes(200)
