"""The ``neural_depth`` integrator: Mitsuba's ``path`` plus selective neural evaluation.

Oracles: Mitsuba's own ``path`` integrator (same estimator, same random-number order, so
the images agree to float32 rounding when no fallback happens: :mod:`tests.helpers.renders`;
bit for bit only on one pinned build, checked behind the ``bitwise`` marker), and renders of
an *analytic* model with the hybrid's ``kd``, ``eta``, ``alpha`` (what the fallback must
produce).
"""

from __future__ import annotations

import copy
import json
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.render.bsdfs.brdf_model import MODEL_BSDF_NAME, register_model_bsdf
from evaluators.render.integrators import integrator_for
from evaluators.render.integrators.neural_depth import (
    NEURAL_DEPTH_INTEGRATOR,
    register_neural_depth_integrator,
)
from evaluators.render.scenes import SceneSetup, build_scene, floor_under_sphere
from tests.helpers.brdf_models import make_model
from tests.helpers.renders import assert_same_render

SETUP = SceneSetup(resolution=(32, 32), spp=16, max_depth=6)


@pytest.fixture(scope="module")
def mi(mi: types.ModuleType) -> types.ModuleType:
    """The LLVM Mitsuba of tests/conftest.py, with this module's plugins registered."""
    mod = mi
    register_model_bsdf(mod)
    register_neural_depth_integrator(mod)
    return mod


@pytest.fixture(scope="module")
def model_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A hybrid model, and an analytic model with the same materials' kd, eta, alpha."""
    root = tmp_path_factory.mktemp("neural_depth")
    hybrid = make_model("hybrid", 16, 2, 4)
    analytic = make_model("analytic", 0, 0, 0)
    paths = {"hybrid": root / "hybrid.json", "analytic": root / "analytic.json"}
    paths["hybrid"].write_text(json.dumps(hybrid))
    paths["analytic"].write_text(json.dumps(analytic))
    return paths


def render(mi: types.ModuleType, bsdf: Any, integrator: dict[str, Any], floor: bool) -> np.ndarray:
    """``sphere_env`` (optionally on a floor of the same material, for interreflections)."""
    scene = build_scene("sphere_env", mi, bsdf, SETUP)
    scene["integrator"] = integrator
    if floor:
        scene["floor"] = floor_under_sphere(mi, bsdf)
    return np.asarray(mi.render(mi.load_dict(scene), seed=3), np.float64)


def test01_same_as_path_for_native_materials(mi: types.ModuleType) -> None:
    bsdf = mi.load_dict(
        {
            "type": "roughplastic",
            "alpha": 0.2,
            "diffuse_reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]},
        }
    )
    ref = render(mi, bsdf, {"type": "path", "max_depth": 6}, floor=True)
    for depth in (-1, 0, 1):
        integ = {"type": NEURAL_DEPTH_INTEGRATOR, "max_depth": 6, "neural_max_depth": depth}
        assert_same_render(render(mi, bsdf, integ, floor=True), ref)


def test02_selective_neural_evaluation(mi: types.ModuleType, model_files: dict[str, Path]) -> None:
    def bsdf(kind: str) -> Any:
        return mi.load_dict(
            {"type": MODEL_BSDF_NAME, "filename": str(model_files[kind]), "material": "gold"}
        )

    def nd(depth: int) -> dict[str, Any]:
        return {"type": NEURAL_DEPTH_INTEGRATOR, "max_depth": 6, "neural_max_depth": depth}

    hybrid, analytic = bsdf("hybrid"), bsdf("analytic")
    path = {"type": "path", "max_depth": 6}
    full = render(mi, hybrid, path, floor=True)
    assert_same_render(render(mi, hybrid, nd(-1), floor=True), full)
    # 0: the analytic model everywhere (traced as f_a of the hybrid: equal up to rounding).
    fa = render(mi, analytic, path, floor=True)
    assert np.allclose(render(mi, hybrid, nd(0), floor=True), fa, rtol=1e-4, atol=1e-6)
    assert np.abs(full - fa).mean() > 0.01 * fa.mean()
    # 1: network at first hits only. On the floor scene that differs from both; on the
    # convex sphere alone no path has a second hit, so it equals the full model.
    one = render(mi, hybrid, nd(1), floor=True)
    assert not np.allclose(one, full) and not np.allclose(one, fa)
    alone = render(mi, hybrid, path, floor=False)
    assert_same_render(render(mi, hybrid, nd(1), floor=False), alone)
    # A depth-2 threshold sits between: closer to the full render than depth 1 is.
    two = render(mi, hybrid, nd(2), floor=True)
    assert np.abs(two - full).mean() < np.abs(one - full).mean()


def test03_integrator_for(mi: types.ModuleType, model_files: dict[str, Path]) -> None:
    plugin = {"type": MODEL_BSDF_NAME, "filename": str(model_files["hybrid"]), "material": "gold"}
    plain = mi.load_dict(plugin)
    hinted = mi.load_dict({**plugin, "neural_max_depth": 1})
    default = {"type": "path", "max_depth": 6}
    assert integrator_for(mi, plain, copy.deepcopy(default)) == default
    assert integrator_for(mi, mi.load_dict({"type": "diffuse"}), default) == default
    swapped = integrator_for(mi, hinted, default)
    assert swapped == {"type": NEURAL_DEPTH_INTEGRATOR, "max_depth": 6, "neural_max_depth": 1}
    img = render(mi, hinted, swapped, floor=False)
    assert np.all(np.isfinite(img)) and img.mean() > 0.0
    with pytest.raises(Exception, match="neural_max_depth must be -1 or >= 0"):
        mi.load_dict({"type": NEURAL_DEPTH_INTEGRATOR, "neural_max_depth": -2})


@pytest.mark.bitwise
def test04_bit_for_bit_with_path_on_a_pinned_build(mi: types.ModuleType) -> None:
    """On one exact build of Mitsuba, Dr.Jit and LLVM the two integrators give the same
    bits (run with ``-m bitwise`` there); elsewhere test01 checks them to rounding."""
    bsdf = mi.load_dict({"type": "roughplastic", "alpha": 0.2})
    ref = render(mi, bsdf, {"type": "path", "max_depth": 6}, floor=True)
    integ = {"type": NEURAL_DEPTH_INTEGRATOR, "max_depth": 6, "neural_max_depth": -1}
    assert np.array_equal(render(mi, bsdf, integ, floor=True), ref)
