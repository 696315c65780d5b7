"""Glints are glints: on the ``glint_closeup`` scene, the tiny-example model's sparkle is in
the material, not in the Monte Carlo noise.

At about 2-4 example texels per pixel (the scene's close-up at 48x36 and 768 texels per uv:
0.089 uv over 36 rows, 1.9 texels per pixel across, 3.0 along v), scratches 32x32, tiled:

- two renders with different sampler seeds have a high-pass correlation
  (:mod:`tests.helpers.glint_highpass`: log luminance minus a 2-pixel Gaussian blur, which
  keeps the 1-3 pixel structure where both glints and per-pixel noise live and drops the
  highlight's envelope that every render shares) of at least 0.7: the same glints;
- control, the independent reference for "speckle is not glints": the smooth GGX of the same
  surface's slopes (no microstructure) in the same renders correlates far less (under
  0.5), so the first check can fail and does on a material without glints;
- moving the lights changes the image measurably: the mean absolute change is at least
  5x the seed-to-seed difference (the Monte Carlo noise), and the high-pass pattern
  changes (correlation under 0.5), since the lit microfacets are others.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from evaluators.render.scenes import CLOSEUP_LIGHTS
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from tests.helpers.glint_highpass import highpass_correlation

#: Texels per uv for about 2-3 example texels per pixel at 48x36 (module docstring).
TEXELS = 768
#: The lights moved sideways by this much (scene units, 3 units away: about 15 degrees).
MOVE = 0.8


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> tuple[Settings, str]:
    data = tmp_path_factory.mktemp("glint_closeup") / "data"
    settings = Settings.from_env({}).with_(data_dir=data, pool_processes=1)
    spec = {
        "kind": "generate.glint",
        "seed": 3,
        "params": {"example": {"procedural": "scratches", "size": 32}, "ndf_resolution": 32},
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    return settings, job.id


def render(env: tuple[Settings, str], method: str, seed: int, lights: Any = None) -> np.ndarray:
    settings, data = env
    params: dict[str, Any] = {
        "scene": "glint_closeup",
        "resolution": [48, 36],
        "spp": 32,
        "max_depth": 2,
        "material": {"glint": {"data": f"job:{data}", "method": method, "texels_per_uv": TEXELS}},
    }
    if lights is not None:
        params["lights"] = lights
    job = run_in_process({"kind": "render", "seed": seed, "params": params}, settings)
    assert job.state == "succeeded", job.error
    (digest,) = [a.digest for a in job.artifacts if a.name == "image.exr"]
    img = read_exr(ArtifactStore(settings.store_dir).open_verified(digest), "image.exr")
    return np.asarray(img, np.float64)


def moved_lights() -> list[dict[str, Any]]:
    return [
        {"position": [p.position[0] + MOVE, *p.position[1:]], "intensity": list(p.intensity)}
        for p in CLOSEUP_LIGHTS
    ]


def test01_glints_are_in_the_material(env: tuple[Settings, str]) -> None:
    a, b = render(env, "tiny_example", 1), render(env, "tiny_example", 2)
    smooth_a, smooth_b = render(env, "smooth_ggx", 1), render(env, "smooth_ggx", 2)
    glints = highpass_correlation(a, b)
    speckle = highpass_correlation(smooth_a, smooth_b)
    assert glints >= 0.7, (glints, speckle)
    assert speckle < 0.5, (glints, speckle)

    moved = render(env, "tiny_example", 1, moved_lights())
    noise = float(np.abs(a - b).mean())
    change = float(np.abs(a - moved).mean())
    assert change >= 5.0 * noise, (change, noise)
    assert highpass_correlation(a, moved) < 0.5, highpass_correlation(a, moved)
