"""``evaluate.tss`` (texture-space shading with temporal reuse, Xu et al. 2025 Sec. 4.2)
through the registry and its simulation, on a c2f model trained here (generate.btf leather
16^2, train.btf 3 epochs).

Identities, each against an independent reference:

- test02: N = 0, a static camera, R = the model's resolution: every frame equals a numpy
  re-implementation (pixel rays, the radiance texture from the numpy ``PortableBtf`` with
  the student's block-centre directions, bilinear clamped lookup) to 1e-5 of the peak;
- test03: a top-down camera whose pixels fall on the texel centres (1:1): the per-texel
  pass's frame equals screen-space shading to 1e-5 of the peak (FLIP < 1e-4); the paper's
  amortised pass is close (FLIP < 0.02: the coarse MLP sees the block centre's directions);
- test04: a static camera: every N gives bit-identical frames to N = 0;
- test05: on a fast path, mean FLIP is non-decreasing in N up to 5e-4 (absolute, about 5 %
  of the values here) and N = 6 is worse than N = 0 by 1e-3; PSNR non-increasing up to
  0.05 dB; ``shading_passes = ceil(frames / (N + 1))``; a frame that N shades itself
  scores exactly as N = 0's;
- test01: ``metrics.json`` and ``path.json`` byte-for-byte the same on a re-run;
- test06: a model ref that is not a train.btf job fails naming ``model``.
"""

from __future__ import annotations

import json
import math
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from evaluators.tss.params import PointLight, TssParams
from evaluators.tss.passes import Plane
from evaluators.tss.path import CameraPath, camera_path
from evaluators.tss.simulate import Simulation, simulate
from jobapi.errors import SpecError
from models.btf.fused import FusedBtf
from models.btf.portable import PortableBtf, read_model, read_textures
from service.settings import Settings
from service.submission import run_in_process
from service.summaries import job_summary
from storage.artifacts import ArtifactStore
from storage.jobs import Job

GENERATE = {
    "kind": "generate.btf",
    "seed": 1,
    "params": {"surface": {"procedural": "leather"}, "resolution": 16, "spp": 4},
}
STATIC = {"rotation_deg": 0.0, "translation_m": 0.0}


class Trained:
    """The module's data: settings, the generate.btf and train.btf jobs, the model."""

    def __init__(self, settings: Settings, data: Job, model: Job) -> None:
        self.settings, self.data, self.model = settings, data, model
        self.store = ArtifactStore(settings.store_dir)
        self.portable = read_model(
            json.loads(self.artifact(model, "model.json")),
            read_textures(self.artifact(model, "textures.npz")),
        )

    def artifact(self, job: Job, name: str) -> bytes:
        (digest,) = [a.digest for a in job.artifacts if a.name == name]
        return self.store.read(digest)

    def run(self, params: dict[str, Any], *, force: bool = False) -> Job:
        spec = {
            "kind": "evaluate.tss",
            "seed": 3,
            "force": force,
            "params": {"model": f"job:{self.model.id}", **params},
        }
        return run_in_process(spec, self.settings)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Trained:
    data_dir = Path(tmp_path_factory.mktemp("tss")) / "data"
    settings = Settings.from_env({}).with_(data_dir=data_dir, pool_processes=2)
    data = run_in_process(GENERATE, settings)
    assert data.state == "succeeded", data.error
    spec = {"kind": "train.btf", "params": {"data": f"job:{data.id}", "model": "c2f", "epochs": 3}}
    model = run_in_process(spec, settings)
    assert model.state == "succeeded", model.error
    return Trained(settings, data, model)


def params_of(trained: Trained, **fields: Any) -> TssParams:
    return TssParams.model_validate_json(json.dumps({"model": f"job:{trained.model.id}", **fields}))


def run_simulation(
    trained: Trained, mi: types.ModuleType, params: TssParams, resolutions: list[int]
) -> tuple[Simulation, CameraPath, dict[int, tuple[np.ndarray, dict[Any, np.ndarray]]]]:
    """The simulation of ``params`` with every frame kept: ``{k: (reference, frames)}``."""
    path = camera_path(params.path, params.effective().frames, np.random.default_rng(0))
    plane = Plane(FusedBtf(trained.portable, mi), params.lights, params.uv_scale)
    kept: dict[int, tuple[np.ndarray, dict[Any, np.ndarray]]] = {}
    sim = simulate(
        plane,
        path,
        resolutions,
        params.intervals,
        params.effective().image,
        amortised=params.texture_pass == "amortised",
        ppd=params.flip_ppd,
        on_frame=lambda k, ref, frames: kept.update({k: (ref, dict(frames))}),
    )
    return sim, path, kept


# -- an independent numpy model of the scene ----------------------------------------------------


def numpy_pixels(path: CameraPath, k: int, width: int, height: int) -> tuple[np.ndarray, ...]:
    """``(hit, u, v, near_edge)`` of frame ``k``'s pixel rays on the plane, float64."""
    eye, (right, up, forward) = path.eye[k], path.basis[k]
    t = path.tan_half_fov
    nx, ny = np.meshgrid(
        ((np.arange(width) + 0.5) / width * 2 - 1) * t,
        (1 - (np.arange(height) + 0.5) / height * 2) * t * height / width,
    )
    d = nx[..., None] * right + ny[..., None] * up + forward
    p = eye + (-eye[2] / d[..., 2])[..., None] * d
    hit = (d[..., 2] < 0) & (np.abs(p[..., 0]) <= 0.5) & (np.abs(p[..., 1]) <= 0.5)
    near_edge = np.abs(np.abs(p[..., :2]) - 0.5).min(axis=-1) < 1e-4
    return hit, p[..., 0] + 0.5, p[..., 1] + 0.5, near_edge


def numpy_radiance_texture(
    model: PortableBtf, lights: list[PointLight], eye: np.ndarray, uv_scale: int
) -> np.ndarray:
    """The texel-matched student's radiance texture ``(R, R, 3)``: each 2 x 2 block's slice
    from :meth:`PortableBtf.slice` at the block centre's directions, ``I / r^2`` per texel."""
    assert model.kind == "c2f"
    n = model.resolution[0]
    r = n * uv_scale
    centres = (np.arange(r) + 0.5) / r - 0.5
    tex = np.zeros((r, r, 3))
    for jb in range(r // 2):
        for ib in range(r // 2):
            q = np.array([(2 * ib + 1) / r - 0.5, (2 * jb + 1) / r - 0.5, 0.0])
            wo = (eye - q) / np.linalg.norm(eye - q)
            for light in lights:
                pos = np.asarray(light.position)
                values = model.slice((pos - q) / np.linalg.norm(pos - q), wo)
                for jt in (2 * jb, 2 * jb + 1):
                    for it in (2 * ib, 2 * ib + 1):
                        d = pos - np.array([centres[it], centres[jt], 0.0])
                        tex[jt, it] += values[jt % n, it % n] / (d @ d) * np.asarray(light.rgb())
    return tex


def numpy_lookup(tex: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear between texel centres, clamped at the edges."""
    r = tex.shape[0]
    x, y = u * r - 0.5, v * r - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    i0, j0 = np.clip(x0.astype(int), 0, r - 1), np.clip(y0.astype(int), 0, r - 1)
    i1, j1 = np.clip(x0.astype(int) + 1, 0, r - 1), np.clip(y0.astype(int) + 1, 0, r - 1)
    return (
        tex[j0, i0] * (1 - fx) * (1 - fy)
        + tex[j0, i1] * fx * (1 - fy)
        + tex[j1, i0] * (1 - fx) * fy
        + tex[j1, i1] * fx * fy
    )


# -- the tests ----------------------------------------------------------------------------------


def test01_smoke_artifacts_summary_and_determinism(trained: Trained) -> None:
    params = {"frames": 6, "intervals": [0, 2], "image": [32, 32]}
    job = trained.run(params)
    assert job.state == "succeeded", job.error
    names = {a.name for a in job.artifacts}
    assert names == {"metrics.json", "timing.json", "path.json", "table.png", "frames.png"}
    metrics = json.loads(trained.artifact(job, "metrics.json"))
    assert [r["label"] for r in metrics["rows"]] == ["32/N=0", "32/N=2"]  # 16 texels x uv 2
    assert all(r["pass"] == "amortised" for r in metrics["rows"])
    assert [r["shading_passes"] for r in metrics["rows"]] == [6, 2]
    timing = json.loads(trained.artifact(job, "timing.json"))
    assert all(row["seconds_per_frame"] > 0 for row in timing["rows"].values())
    assert trained.artifact(job, "frames.png")[:8] == b"\x89PNG\r\n\x1a\n"
    table = job_summary(job, trained.store)
    assert table is not None and table["labels"] == ["32/N=0", "32/N=2", "screen space"]
    assert table["rows"]["32/N=2"]["relative_cost"] == timing["rows"]["32/N=2"]["relative_cost"]
    # (d) The same spec again: metrics.json and path.json byte for byte (timings may differ).
    again = trained.run(params, force=True)
    assert again.state == "succeeded", again.error
    assert again.id != job.id
    for name in ("metrics.json", "path.json"):
        assert trained.artifact(again, name) == trained.artifact(job, name), name


def test02_static_n0_frames_are_the_texture_looked_up(
    trained: Trained, mi: types.ModuleType
) -> None:
    """(a) R = the model's resolution (uv_scale 1), N = 0, a static camera at 45 degrees:
    frames = the numpy radiance texture looked up at the numpy pixel uv."""
    params = params_of(trained, uv_scale=1, frames=2, intervals=[0], image=[48, 40], path=STATIC)
    sim, path, kept = run_simulation(trained, mi, params, [16])
    assert sim.amortised == {16: True}
    tex = numpy_radiance_texture(trained.portable, params.lights, path.eye[0], 1)
    hit, u, v, near_edge = numpy_pixels(path, 0, 48, 40)
    assert hit.mean() > 0.5 and near_edge.sum() < 10
    expect = np.where(hit[..., None], numpy_lookup(tex, u, v), 0.0)
    for k in range(2):
        frame = kept[k][1][(16, 0)]
        err = np.abs(frame - expect)[~near_edge]
        assert err.max() <= 1e-5 * expect.max(), (k, err.max())


def test03_one_to_one_pixels_equal_screen_space(trained: Trained, mi: types.ModuleType) -> None:
    """(a) A top-down camera whose 32 x 32 pixels fall on the 32 x 32 texel centres: the
    per-texel pass's frames are the screen-space frames; the amortised pass is close."""
    fov = math.degrees(2 * math.atan(0.5 / 1.2))  # the plane (side 1) fills the view at 1.2 m
    path = {**STATIC, "elevation_deg": 90.0, "distance_m": 1.2, "fov_deg": fov}
    flips = {}
    for tp in ("per_texel", "amortised"):
        params = params_of(
            trained, frames=1, intervals=[0], image=[32, 32], path=path, texture_pass=tp
        )
        sim, _, kept = run_simulation(trained, mi, params, [32])
        ref, frames = kept[0]
        assert ref.max(axis=2).min() > 0.0  # every pixel on the plane
        if tp == "per_texel":
            assert np.abs(frames[(32, 0)] - ref).max() <= 1e-5 * ref.max()
        flips[tp] = sim.series[(32, 0)].flip[0]
    assert flips["per_texel"] < 1e-4
    assert flips["per_texel"] < flips["amortised"] < 0.02


def test04_static_camera_every_interval_equals_n0(trained: Trained, mi: types.ModuleType) -> None:
    """(b) Nothing moves: reuse loses nothing, for the amortised pass (R 32) and the per-texel
    one (R 24)."""
    params = params_of(trained, frames=7, image=[24, 24], path=STATIC)
    sim, _, kept = run_simulation(trained, mi, params, [32, 24])
    assert sim.amortised == {32: True, 24: False}
    for k, (_, frames) in kept.items():
        for r in (32, 24):
            for n in (1, 2, 4, 6):
                np.testing.assert_array_equal(frames[(r, n)], frames[(r, 0)], err_msg=f"{k} {n}")
    for r in (32, 24):
        assert all(sim.series[(r, n)].flip == sim.series[(r, 0)].flip for n in (1, 2, 4, 6))
        assert sim.series[(r, 4)].shading_frames == [0, 5]


def test05_moving_flip_non_decreasing_in_n(trained: Trained) -> None:
    """(c) A fast head (12 FPS spacing, 10 cm amplitude: about 6x the default per-frame
    motion) at R 32 (amortised) and 96 (per texel)."""
    frames = 14
    job = trained.run(
        {
            "frames": frames,
            "image": [32, 32],
            "resolutions": [32, 96],
            "path": {"fps": 12.0, "translation_m": 0.1},
        }
    )
    assert job.state == "succeeded", job.error
    metrics = json.loads(trained.artifact(job, "metrics.json"))
    rows = {(r["resolution"], r["interval"]): r for r in metrics["rows"]}
    intervals = [0, 1, 2, 4, 6]
    for r in (32, 96):
        flip = [rows[(r, n)]["flip_mean"] for n in intervals]
        psnr = [rows[(r, n)]["psnr_mean"] for n in intervals]
        assert all(b >= a - 5e-4 for a, b in zip(flip, flip[1:], strict=False)), (r, flip)
        assert flip[-1] >= flip[0] + 1e-3, (r, flip)
        assert all(b <= a + 0.05 for a, b in zip(psnr, psnr[1:], strict=False)), (r, psnr)
        for n in intervals:
            assert rows[(r, n)]["shading_passes"] == math.ceil(frames / (n + 1))
            own = metrics["per_frame"][f"{r}/N={n}"]["flip"]
            base = metrics["per_frame"][f"{r}/N=0"]["flip"]
            for k in range(0, frames, n + 1):  # shaded at k itself: N = 0's texture
                assert own[k] == base[k]
    shading = json.loads(trained.artifact(job, "path.json"))["shading_frames"]
    assert shading == {str(n): list(range(0, frames, n + 1)) for n in intervals}
    assert metrics["motion"]["translation_mm_mean"] > 10.0


def test06_model_must_be_a_train_btf_job(trained: Trained) -> None:
    """(e) The model ref names a generate.btf job, or no job: the job fails naming 'model';
    an artifact ref is refused before queueing."""
    job = run_in_process(
        {"kind": "evaluate.tss", "params": {"model": f"job:{trained.data.id}"}}, trained.settings
    )
    assert job.state == "failed"
    assert job.error is not None and job.error.startswith("model:") and "train.btf" in job.error
    job = run_in_process(
        {"kind": "evaluate.tss", "params": {"model": "job:" + "0" * 32}}, trained.settings
    )
    assert job.state == "failed" and job.error is not None and job.error.startswith("model:")
    with pytest.raises(SpecError) as err:
        run_in_process(
            {"kind": "evaluate.tss", "params": {"model": f"job:{trained.model.id}/model.json"}},
            trained.settings,
        )
    assert any("model" in loc for loc, _ in err.value.errors)


def test07_amortised_at_every_resolution(trained: Trained, mi: types.ModuleType) -> None:
    """``amortised_all``: the student's 2 x 2 amortisation at any even R. At the
    texel-matched R its block pass (gathers, bilinear fine features at the texel centres)
    equals the contiguous :meth:`FusedBtf.shade_texture` pass, which test02 checks against
    numpy, to 1e-5 of the peak; at an unmatched R it runs (``pass`` amortised) and stays
    close to the per-texel pass of the same R (only ``z_c`` is shared per block: FLIP <
    0.02 on the 1:1 top-down view, as test03's bound for the matched pass)."""
    params = params_of(trained, uv_scale=2, lights=[{"position": [0.3, 0.2, 1.0],
                                                     "intensity": 2.0}])  # fmt: skip
    plane = Plane(FusedBtf(trained.portable, mi), params.lights, params.uv_scale)
    eye = np.array([0.2, -0.4, 0.9])
    cam = plane.camera(eye, np.eye(3), 0.5)
    matched = np.stack([np.asarray(c) for c in plane.shade(32, cam, amortised=True)])
    blocks = np.stack([np.asarray(c) for c in plane._shade_any_blocks(32, cam)])
    assert np.abs(blocks - matched).max() <= 1e-5 * matched.max()
    assert plane.amortises(24, True) and not plane.amortises(24, False)
    assert not plane.amortises(25, True)  # an odd R has no 2 x 2 blocks
    fov = math.degrees(2 * math.atan(0.5 / 1.2))
    path = {**STATIC, "elevation_deg": 90.0, "distance_m": 1.2, "fov_deg": fov}
    flips = {}
    for tp in ("per_texel", "amortised_all"):
        p = params_of(trained, frames=1, intervals=[0], image=[24, 24], path=path, texture_pass=tp)
        path_ = camera_path(p.path, 1, np.random.default_rng(0))
        pl = Plane(FusedBtf(trained.portable, mi), p.lights, p.uv_scale)
        sim = simulate(pl, path_, [24], [0], (24, 24), amortised=tp != "per_texel",
                       everywhere=tp == "amortised_all", ppd=p.flip_ppd)  # fmt: skip
        assert sim.amortised == {24: tp == "amortised_all"}
        flips[tp] = sim.series[(24, 0)].flip[0]
    assert flips["per_texel"] < 1e-4 and flips["per_texel"] < flips["amortised_all"] < 0.02
