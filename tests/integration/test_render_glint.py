"""``{"glint": ...}`` renders through the ``render`` kind: the tiny-example model and the Yan
et al. reference over the same microstructure agree, and differ from a different one.

References: the Yan reference (Eq. 1 over the lobes of the exported map) for the
tiny-example render; a second, different example as the control; errors in the spec name
the field.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.jobs import Job


def image(settings: Settings, job: Job) -> np.ndarray:
    (digest,) = [a.digest for a in job.artifacts if a.name == "image.exr"]
    return read_exr(ArtifactStore(settings.store_dir).open_verified(digest), "image.exr")


def glint_job(settings: Settings, kind: str, seed: int) -> Job:
    spec = {
        "kind": "generate.glint",
        "seed": seed,
        "params": {"example": {"procedural": kind, "size": 16}, "ndf_resolution": 48},
    }
    job = run_in_process(spec, settings)
    assert job.state == "succeeded", job.error
    return job


def render(settings: Settings, material: dict[str, Any], spp: int = 16) -> Job:
    spec = {
        "kind": "render",
        "seed": 2,
        "params": {
            "scene": "bent_quad",
            "resolution": [64, 48],
            "spp": spp,
            "max_depth": 2,
            "material": {"glint": material},
        },
    }
    return run_in_process(spec, settings)


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> tuple[Settings, Job, Job]:
    data = tmp_path_factory.mktemp("glint_render") / "data"
    settings = Settings.from_env({}).with_(data_dir=data, pool_processes=1)
    return settings, glint_job(settings, "isotropic_noise", 3), glint_job(settings, "scratches", 4)


def test01_tiny_example_against_yan(env: tuple[Settings, Job, Job]) -> None:
    settings, iso, scratches = env
    common = {"texels_per_uv": 96, "conductor": "Ag"}
    jobs = {
        "tiny": render(settings, {"data": f"job:{iso.id}", "method": "tiny_example", **common}),
        "yan": render(settings, {"data": f"job:{iso.id}", "method": "yan", **common}),
        "other": render(settings, {"data": f"job:{scratches.id}", "method": "yan", **common}),
    }
    for name, job in jobs.items():
        assert job.state == "succeeded", (name, job.error)
    tiny, yan, other = (
        image(settings, jobs[k]).astype(np.float64) for k in ("tiny", "yan", "other")
    )
    assert tiny.max() > 5 * np.median(tiny[tiny > 0])  # glints: sparse bright pixels
    err = np.abs(tiny - yan).mean() / yan.mean()
    control = np.abs(other - yan).mean() / yan.mean()
    # Same microstructure, two evaluators: the difference is the lobe model at 2 seeds per
    # texel against the export's at 2 per texel, the maps' resolution (R = 48) and 16 spp
    # of noise; a different example differs several times more.
    assert err < 0.5 * control, (err, control)
    assert abs(tiny.mean() / yan.mean() - 1.0) < 0.1


def test02_clearcoat_adds_a_layer(env: tuple[Settings, Job, Job]) -> None:
    settings, iso, scratches = env
    base = {"data": f"job:{iso.id}", "texels_per_uv": 96}
    plain = render(settings, base, spp=8)
    coat = render(settings, {**base, "clearcoat": {"data": f"job:{scratches.id}"}}, spp=8)
    assert plain.state == "succeeded" and coat.state == "succeeded", coat.error
    assert not np.allclose(image(settings, plain), image(settings, coat))


def test03_errors_name_the_field(env: tuple[Settings, Job, Job]) -> None:
    settings, iso, _ = env
    job = render(settings, {"data": f"job:{iso.id}", "conductor": "Unobtainium"})
    assert job.state == "failed" and "material.glint.conductor" in str(job.error)
    stochastic = {"distribution": "stochastic"}
    job = render(settings, {"data": f"job:{iso.id}", "surface": stochastic, "sampling": "pndf"})
    assert job.state == "failed" and "material.glint" in str(job.error), job.error
    assert "stochastic" in str(job.error)
    job = render(settings, {"data": "job:" + "0" * 32})
    assert job.state == "failed" and "material.glint.data" in str(job.error)


def test04_stochastic_tiny_example_against_yan(env: tuple[Settings, Job, Job]) -> None:
    """A stochastic surface renders with the tiny example's Dr.Jit twin: against Yan's
    reference on the same exported microstructure, closer than a different example is."""
    settings, iso, scratches = env
    common = {"texels_per_uv": 96, "conductor": "Ag", "surface": {"distribution": "stochastic"}}
    jobs = {
        "tiny": render(
            settings, {"data": f"job:{scratches.id}", "method": "tiny_example", **common}
        ),
        "yan": render(
            settings, {"data": f"job:{scratches.id}", "method": "yan", "yan_rate": 2, **common}
        ),
        "other": render(
            settings, {"data": f"job:{iso.id}", "method": "yan", "yan_rate": 2, **common}
        ),
    }
    for name, job in jobs.items():
        assert job.state == "succeeded", (name, job.error)
    tiny, yan, other = (
        image(settings, jobs[k]).astype(np.float64) for k in ("tiny", "yan", "other")
    )
    err = np.abs(tiny - yan).mean() / yan.mean()
    control = np.abs(other - yan).mean() / yan.mean()
    assert err < 0.5 * control, (err, control)


def test05_hierarchical_yan_renders_the_brute_force_image(
    env: tuple[Settings, Job, Job],
) -> None:
    """``yan_eval: "hierarchical"`` through the render kind: the same image as the brute
    force (same seed, same sampled directions; the P-NDF agrees to 1e-4 relative plus the
    truncation bound, ``tests/unit/materials/glints/test_pndf_yan_hier.py``), so every
    pixel within 1e-3 of the image's peak; and its rows' config names the evaluation."""
    settings, _, scratches = env
    spec = {"data": f"job:{scratches.id}", "method": "yan", "texels_per_uv": 96, "yan_rate": 2}
    brute = render(settings, spec, spp=4)
    hier = render(settings, {**spec, "yan_eval": "hierarchical"}, spp=4)
    assert brute.state == "succeeded" and hier.state == "succeeded", hier.error
    a, b = image(settings, hier).astype(np.float64), image(settings, brute).astype(np.float64)
    assert b.max() > 0
    assert np.abs(a - b).max() <= 1e-3 * b.max()
    with pytest.raises(SpecError, match="yan_eval"):
        render(settings, {**spec, "yan_eval": "octree"}, spp=4)
