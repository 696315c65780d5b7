"""The camera path and params of ``evaluate.tss``: closed-form poses, bounds on the per-frame
motion derived from the sinusoids, seeding, and the params' refusals."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError

from evaluators.tss.params import PathSpec, TssParams
from evaluators.tss.path import base_pose, camera_path

MODEL = "job:" + "a" * 32


def test01_static_path_is_the_base_pose() -> None:
    spec = PathSpec(rotation_deg=0.0, translation_m=0.0, elevation_deg=30.0, azimuth_deg=20.0)
    path = camera_path(spec, 5, np.random.default_rng(1))
    eye, basis = base_pose(spec)
    np.testing.assert_allclose(path.eye, np.broadcast_to(eye, (5, 3)), atol=1e-12)
    np.testing.assert_allclose(path.basis, np.broadcast_to(basis, (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(basis @ basis.T, np.eye(3), atol=1e-12)  # orthonormal
    np.testing.assert_allclose(np.cross(basis[0], basis[1]), -basis[2], atol=1e-12)
    np.testing.assert_allclose(basis[2], -eye / np.linalg.norm(eye), atol=1e-12)  # at the origin
    assert abs(basis[0][2]) < 1e-12 and basis[1][2] > 0.0  # right horizontal, up upwards
    el = math.radians(30.0)
    assert eye[2] == pytest.approx(spec.distance_m * math.sin(el))
    assert path.motion()["translation_mm_max"] == 0.0


def test02_straight_down() -> None:
    eye, (right, up, forward) = base_pose(PathSpec(elevation_deg=90.0, distance_m=2.0))
    np.testing.assert_allclose(eye, [0, 0, 2], atol=1e-12)
    np.testing.assert_allclose(forward, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)  # azimuth -90: u to the right
    np.testing.assert_allclose(up, [0, 1, 0], atol=1e-12)  # v upwards in the image


def test03_motion_bounded_by_the_sinusoids() -> None:
    """Per frame, each degree of freedom changes by at most amplitude * 2 pi f_w / fps, with
    f_w the 1/k-weighted mean frequency: rotation <= sqrt(3) of that, the eye's travel <=
    sqrt(3) of the translation's plus the pivot arm times the rotation."""
    spec = PathSpec(rotation_deg=12.0, translation_m=0.08, fps=30.0, pivot_m=0.15)
    path = camera_path(spec, 60, np.random.default_rng(7))
    w = 1.0 / np.arange(1, 4)
    rate = 2 * math.pi * float((w * np.asarray(spec.frequencies_hz)).sum() / w.sum()) / spec.fps
    rot = math.sqrt(3) * math.radians(spec.rotation_deg) * rate
    travel = math.sqrt(3) * spec.translation_m * rate + spec.pivot_m * rot
    m = path.motion()
    assert 0.0 < m["rotation_deg_max"] <= math.degrees(rot) * 1.01
    assert 0.0 < m["translation_mm_max"] <= travel * 1e3 * 1.01
    eye0, _ = base_pose(spec)
    arm = spec.pivot_m * math.radians(spec.rotation_deg) * math.sqrt(3)
    assert np.linalg.norm(path.eye - eye0, axis=1).max() <= math.sqrt(3) * 0.08 + arm


def test04_seeded() -> None:
    spec = PathSpec()
    a, b = (
        camera_path(spec, 10, np.random.default_rng(3)),
        camera_path(spec, 10, np.random.default_rng(3)),
    )
    c = camera_path(spec, 10, np.random.default_rng(4))
    np.testing.assert_array_equal(a.eye, b.eye)
    assert not np.allclose(a.eye, c.eye)


def params(**fields: object) -> TssParams:
    return TssParams.model_validate_json(json.dumps({"model": MODEL, **fields}))


def test05_params_defaults_and_presets() -> None:
    p = params()
    assert p.intervals == [0, 1, 2, 4, 6] and p.effective().frames == 48 and p.uv_scale == 2
    assert p.effective().image == (128, 128) and len(p.lights) == 3
    assert p.texture_resolutions(16) == [32]  # texel-matched: the model's 16 x uv_scale 2
    paper = params(preset="paper")
    assert paper.effective().frames == 90 and paper.effective().image == (512, 512)
    assert paper.texture_resolutions(400) == [800, 1200, 1600, 2000]
    assert params(intervals=[4, 0], resolutions=[64, 8]).intervals == [0, 4]
    light = params(lights=[{"position": [0, 0, 1], "intensity": [1, 2, 3]}]).lights[0]
    assert light.rgb() == (1.0, 2.0, 3.0)


@pytest.mark.parametrize(
    ("fields", "where"),
    [
        ({"intervals": [1, 1]}, "intervals"),
        ({"intervals": [-1]}, "intervals"),
        ({"resolutions": [32, 32]}, "resolutions"),
        ({"image": [4, 64]}, "image"),
        ({"lights": [{"position": [0, 0, -0.5]}]}, "lights.0.position"),
        ({"lights": [{"position": [0, 0, 1], "intensity": -1}]}, "lights.0.intensity"),
        ({"path": {"elevation_deg": 0}}, "path.elevation_deg"),
        ({"model": MODEL + "/model.json"}, "model"),
        ({"frame": 3}, "frame"),
    ],
)
def test06_params_refused(fields: dict[str, object], where: str) -> None:
    with pytest.raises(ValidationError) as err:
        params(**fields)
    locs = {".".join(str(p) for p in e["loc"]) for e in err.value.errors()}
    assert any(loc.startswith(where) for loc in locs), locs
