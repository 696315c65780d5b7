"""Glints are glints: at a close-up footprint (about 2 texels per pixel) a stochastic
tiny-example surface shows a pattern fixed to the surface, not Monte Carlo speckle.

References (no model of the renderer's own): the high-pass images (the image minus its
3 x 3 box blur) of two renders that differ only in the sampler's seed correlate by at least
0.7 (noise would give about 0); moving one light changes the pattern (the high-pass
correlation of two light positions falls below the seed-to-seed one by 0.2 or more).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import Job

LIGHTS = [
    {"position": [-2.5, 3.0, 2.0], "intensity": [40.0, 38.0, 36.0]},
    {"position": [2.5, 2.5, 2.5], "intensity": [20.0, 22.0, 24.0]},
]


def _image(settings: Settings, job: Job) -> np.ndarray:
    (digest,) = [a.digest for a in job.artifacts if a.name == "image.exr"]
    return read_exr(ArtifactStore(settings.store_dir).open_verified(digest), "image.exr")


def _render(settings: Settings, data: str, seed: int, lights: list[dict[str, Any]]) -> np.ndarray:
    spec = {
        "kind": "render",
        "seed": seed,
        "params": {
            "scene": "bent_quad",
            "resolution": [64, 48],
            "spp": 32,
            "max_depth": 2,
            "lights": lights,
            "material": {
                "glint": {
                    "data": data,
                    "texels_per_uv": 96,
                    "surface": {"distribution": "stochastic"},
                }
            },
        },
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    return _image(settings, job).astype(np.float64).mean(axis=-1)


def _high_pass(img: np.ndarray) -> np.ndarray:
    pad = np.pad(img, 1, mode="edge")
    blur = (
        sum(
            pad[dy : dy + img.shape[0], dx : dx + img.shape[1]]
            for dy in range(3)
            for dx in range(3)
        )
        / 9.0
    )
    return (img - blur)[1:-1, 1:-1]


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = _high_pass(a).ravel(), _high_pass(b).ravel()
    return float(np.corrcoef(a, b)[0, 1])


@pytest.fixture(scope="module")
def settings(tmp_path_factory: pytest.TempPathFactory) -> Settings:
    data = tmp_path_factory.mktemp("glints_are_glints") / "data"
    return Settings.from_env({}).with_(data_dir=data, pool_processes=1)


def test01_pattern_is_fixed_to_the_surface(settings: Settings) -> None:
    spec = {
        "kind": "generate.glint",
        "seed": 4,
        "params": {"example": {"procedural": "scratches", "size": 16}, "ndf_resolution": 48},
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    data = f"job:{job.id}"
    a = _render(settings, data, 1, LIGHTS)
    b = _render(settings, data, 2, LIGHTS)
    moved = [{**LIGHTS[0], "position": [-1.0, 3.0, 2.8]}, LIGHTS[1]]
    c = _render(settings, data, 1, moved)
    seeds, light = _corr(a, b), _corr(a, c)
    assert seeds >= 0.7, (seeds, light)
    assert light < seeds - 0.2, (seeds, light)
