"""``generate.fabric`` through the registry: validation, shards, artifacts, resumption.

Oracles: the npz layout the issue fixes (keys, shapes, dtypes); the query design recomputed
independently by :func:`generators.fabric.queries.design_queries` from the recorded seeds;
the numpy reference estimator against the default Dr.Jit backend (same points, float32
round-off apart); byte-identical shards for the same spec; sentinel shard reuse after a
crash (as ``test_worker.py`` test04).
"""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np
import pytest

from generators.fabric.params import FabricScene
from generators.fabric.queries import design_queries
from generators.fabric.scene_queries import scene_queries
from jobapi.errors import SpecError
from service.settings import Settings
from service.submission import run_in_process, submit
from storage.artifacts import ArtifactStore
from storage.formats.exr import read_exr
from storage.formats.npz import npz_bytes
from storage.jobs import Job, JobStore
from tests.helpers.manifests import measured

KIND = "generate.fabric"
#: The small preset, cut down: 3 materials x 256 queries x 64 samples, 6 shards.
PARAMS: dict[str, Any] = {
    "preset": "small",
    "queries_per_material": 256,
    "shard_queries": 128,
    "samples": 64,
    "map_resolution": 16,
}
KEYS = {
    "material": ((), np.int32),
    "center": ((2,), np.float32),
    "size": ((), np.float32),
    "wi": ((3,), np.float32),
    "wo": ((3,), np.float32),
    "value": ((4,), np.float32),
    "stderr": ((4,), np.float32),
}


def spec(params: dict[str, Any], force: bool = False) -> dict[str, Any]:
    return {"kind": KIND, "seed": 5, "params": params, "force": force}


def read(settings: Settings, job: Job, name: str) -> bytes:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return ArtifactStore(settings.store_dir).read(digest)


def shard(settings: Settings, job: Job, i: int) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(read(settings, job, f"shard-{i:04d}.npz"))) as z:
        return {k: z[k] for k in z.files}


def digests(job: Job) -> dict[str, str]:
    return {a.name: a.digest for a in job.artifacts}


def test01_small_run_artifacts_and_determinism(settings: Settings) -> None:
    job = run_in_process(spec(PARAMS), settings)
    assert job.state == "succeeded", job.error
    names = {a.name for a in job.artifacts}
    doc = json.loads(read(settings, job, "materials.json"))
    mats = doc["materials"]
    assert [m["pattern"] for m in mats] == ["plain", "twill_3x3", "satin_5x5"]
    maps = {m["maps"][k] for m in mats for k in ("normal", "orientation")}
    shards = {f"shard-{i:04d}.npz" for i in range(6)}
    assert names == shards | maps | {"materials.json", "stats.json", "preview.png"}
    for i in range(6):
        z = shard(settings, job, i)
        assert set(z) == set(KEYS)
        for key, (tail, dtype) in KEYS.items():
            assert z[key].shape == (128, *tail) and z[key].dtype == dtype, key
        m = mats[i // 2]
        assert np.all(z["material"] == i // 2) and m["shards"][i % 2] == f"shard-{i:04d}.npz"
        value, err = z["value"], z["stderr"]
        assert np.all(np.isfinite(value)) and np.all(value >= 0)
        assert np.all(np.isfinite(err)) and np.all(err[value > 0] > 0)
        assert np.count_nonzero(value.sum(axis=1)) > 100  # most queries see some yarn
        q = design_queries(m["design_seed"], 128 * (i % 2), 128)
        np.testing.assert_array_equal(z["center"], q.centre.astype(np.float32))
        np.testing.assert_array_equal(z["wi"], q.wi.astype(np.float32))
        assert np.any(z["wi"][:, 2] < 0) and np.any(z["wi"][:, 2] > 0)  # BTDF and BRDF
    for m in mats:
        p = m["params"]
        assert p["gap"] == 0.2 and len(p["psi_deg"]) == 2 and len(p["kd_warp"]) == 3
        normal = read_exr_bytes(settings, job, m["maps"]["normal"])
        assert normal.shape == (16, 16, 3)
        np.testing.assert_allclose(np.linalg.norm(normal, axis=2), 1.0, atol=1e-4)
    stats = json.loads(read(settings, job, "stats.json"))
    assert stats["samples"] == 3 * 256 * 64 and "samples_per_second" not in stats
    # The throughput is a timing: in the manifest, not in an artifact (same spec, same bytes).
    timed = measured(settings, job)["throughput"]
    # samples per second is samples / seconds of the unrounded time; seconds is rounded to
    # 1 ms (+- 0.5 ms) and the rate to 0.1 (+- 0.05)
    n, s, rate = stats["samples"], timed["seconds"], timed["samples_per_second"]
    assert s > 0 and n / (s + 5e-4) - 0.05 <= rate <= n / max(s - 5e-4, 1e-9) + 0.05
    again = run_in_process(spec(PARAMS, force=True), settings)
    assert again.state == "succeeded" and again.id != job.id
    assert digests(again) == digests(job)


def read_exr_bytes(settings: Settings, job: Job, name: str) -> np.ndarray:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return read_exr(ArtifactStore(settings.store_dir).open_verified(digest), name)


def test02_numpy_backend_matches_drjit(settings: Settings) -> None:
    params = {**PARAMS, "patterns": ["twill_3x3"], "sampler": "independent"}
    ref = run_in_process(spec({**params, "backend": "numpy"}), settings)
    fast = run_in_process(spec(params), settings)
    assert ref.state == fast.state == "succeeded", (ref.error, fast.error)
    for i in range(2):
        a, b = shard(settings, ref, i), shard(settings, fast, i)
        np.testing.assert_array_equal(a["wo"], b["wo"])
        np.testing.assert_allclose(a["value"], b["value"], rtol=1e-3, atol=1e-6)
        np.testing.assert_allclose(a["stderr"], b["stderr"], rtol=1e-2, atol=1e-6)


def test03_recorded_shard_is_reused(settings: Settings) -> None:
    params = {**PARAMS, "patterns": ["plain"], "backend": "numpy"}
    jobs = JobStore(settings.db_path)
    store = ArtifactStore(settings.store_dir)
    job, created = submit(spec(params), jobs, store)
    assert created
    sentinel = npz_bytes({"sentinel": np.array([7])})
    # A shard is recorded under its artifact name, with the npz bytes themselves (stored
    # once: no pickled result beside them).
    jobs.record_shard(job.id, "shard-0001.npz", store.put_bytes(sentinel).digest)
    done = run_in_process(spec(params), settings)
    assert done.id == job.id and done.state == "succeeded", done.error
    assert read(settings, done, "shard-0001.npz") == sentinel
    assert set(shard(settings, done, 0)) == set(KEYS)  # the other shard was computed
    jobs.close()


@pytest.mark.parametrize(
    ("params", "field"),
    [
        ({"patterns": ["plaid"]}, "patterns"),
        ({"samples": 0}, "samples"),
        ({"samples": 24}, "samples"),  # sobol: 24 / 4 replicates is not a power of two
        ({"sampler": "halton"}, "sampler"),
        ({"texture_sets": 0}, "texture_sets"),
        ({"bogus": 1}, "bogus"),
        ({"scene": {"name": "sphere_env"}}, "scene.name"),  # not a floor scene
        ({"scene": {"name": "cloth_plain"}}, "scene.name"),
        ({"scene": {"name": "cloth_plane", "resolution": [4, 4]}}, "scene.resolution"),
        ({"scene": {"name": "cloth_plane"}, "sizes": "log_uniform"}, "sizes"),
        ({"scene": {"name": "cloth_plane"}, "btdf_fraction": 0.2}, "btdf_fraction"),
        ({"scene": {"name": "plane_points", "lights": []}}, "lights"),
        ({"yarn_profile": "round"}, "yarn_profile"),
    ],
)
def test04_bad_specs_name_the_field(settings: Settings, params: dict, field: str) -> None:
    with pytest.raises(SpecError) as info:
        run_in_process(spec(params), settings)
    assert field in str(info.value)


def test05_progress_per_shard_in_batches(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Long jobs report: per material while writing maps, then per finished shard in
    every batch of ``BATCH_SHARDS``, monotonically, up to the preview and 1.0."""
    import generators.fabric.kind as fabric
    from jobapi.context import JobContext

    reports: list[tuple[float, str | None]] = []
    original = JobContext.progress

    def record(self: JobContext, fraction: float, message: str | None = None) -> None:
        reports.append((fraction, message))
        original(self, fraction, message)

    monkeypatch.setattr(JobContext, "progress", record)
    monkeypatch.setattr(fabric, "BATCH_SHARDS", 4)
    params = {**PARAMS, "queries_per_material": 64, "shard_queries": 16, "samples": 16}
    job = run_in_process(spec({**params, "backend": "numpy"}), settings)
    assert job.state == "succeeded", job.error
    fractions = [f for f, _ in reports]
    assert all(b >= a - 1e-9 for a, b in zip(fractions, fractions[1:], strict=False))
    assert fractions[-1] == 1.0
    messages = [m for _, m in reports if m]
    assert [m for m in messages if m.startswith("maps:")] == [
        f"maps: {i}/3 material(s)" for i in range(3)
    ]
    shard_reports = [m for m in messages if m.startswith("shards:")]
    assert shard_reports == [f"shards: {k}/4" for _ in range(3) for k in range(1, 5)]
    assert "preview" in messages


def test06_log_uniform_size_design(settings: Settings) -> None:
    params = {**PARAMS, "patterns": ["plain"], "sizes": "log_uniform"}
    job = run_in_process(spec(params), settings)
    assert job.state == "succeeded", job.error
    doc = json.loads(read(settings, job, "materials.json"))
    assert doc["config"]["sizes"] == "log_uniform"
    seed = doc["materials"][0]["design_seed"]
    ref = design_queries(seed, 0, 128, sizes="log_uniform")
    got = shard(settings, job, 0)
    np.testing.assert_array_equal(got["size"], ref.size.astype(np.float32))
    assert got["size"].min() >= 0.01 and got["size"].max() <= 5.0
    # The default design's materials.json has no "sizes" key (its bytes are unchanged).
    default = run_in_process(spec({**PARAMS, "patterns": ["plain"]}), settings)
    assert "sizes" not in json.loads(read(settings, default, "materials.json"))["config"]


def test06a_beta_preset_shares_one_query_set(settings: Settings) -> None:
    """The ``beta`` preset's materials differ only in beta: every one of a texture set has the
    identical query arrays (centres, sizes, directions: a paired design), its values differ
    with beta, and the shared design seed is the one materials.json records."""
    params = {"preset": "beta", "patterns": ["plain"], "shading_sets": 3,
              "queries_per_material": 128, "shard_queries": 128, "samples": 64,
              "map_resolution": 16}  # fmt: skip
    job = run_in_process(spec(params), settings)
    assert job.state == "succeeded", job.error
    mats = json.loads(read(settings, job, "materials.json"))["materials"]
    assert len(mats) == 3 and len({m["design_seed"] for m in mats}) == 1
    shards = [shard(settings, job, i) for i in range(3)]
    for z in shards[1:]:
        for key in ("center", "size", "wi", "wo"):
            np.testing.assert_array_equal(z[key], shards[0][key], err_msg=key)
        assert not np.array_equal(z["value"], shards[0]["value"])  # beta changes the values
    ref = design_queries(mats[0]["design_seed"], 0, 128)
    np.testing.assert_array_equal(shards[0]["wo"], ref.wo.astype(np.float32))


def test06b_jin_yarn_profile_is_recorded_and_used(settings: Settings) -> None:
    """``yarn_profile: jin`` reaches every material: recorded in materials.json (config and
    params), its maps are those of :func:`materials.fabric.yarn.rasterize` with Jin's
    profile (the reference), and the default spec's documents carry no such key."""
    from materials.fabric.params import FabricParams
    from materials.fabric.yarn import rasterize

    base = {**PARAMS, "patterns": ["twill_3x3"], "queries_per_material": 128, "samples": 16}
    job = run_in_process(spec({**base, "yarn_profile": "jin"}), settings)
    assert job.state == "succeeded", job.error
    doc = json.loads(read(settings, job, "materials.json"))
    assert doc["config"]["yarn_profile"] == "jin"
    (m,) = doc["materials"]
    assert m["params"]["yarn_profile"] == "jin"
    params = FabricParams(**m["params"])
    normal = read_exr_bytes(settings, job, m["maps"]["normal"])
    ref = np.flip(rasterize(params, 16).normal, axis=0)  # the map file is top-down
    smooth = np.flip(rasterize(params.replace(yarn_profile="smooth"), 16).normal, axis=0)
    assert np.abs(normal - ref).max() < np.abs(normal - smooth).max()
    default = run_in_process(spec(base), settings)
    ddoc = json.loads(read(settings, default, "materials.json"))
    assert "yarn_profile" not in ddoc["config"]
    assert "yarn_profile" not in ddoc["materials"][0]["params"]
    assert digests(default)["materials.json"] != digests(job)["materials.json"]


def test07_scene_driven_design(settings: Settings) -> None:
    """``scene``: the shards hold :func:`scene_queries` of the recorded seeds (sizes from
    the pixel footprints, tile units; the satin 5x10 tile's aspect 1/2 enters the size),
    and ``materials.json`` records the resolved scene; the same spec gives the same bytes."""
    scene = {"name": "cloth_plane", "resolution": [64, 48], "tiles_per_uv": 8}
    params = {**PARAMS, "patterns": ["plain", "satin_5x10"], "samples": 16, "scene": scene}
    params |= {"queries_per_material": 128, "shard_queries": 64, "backend": "numpy"}
    job = run_in_process(spec(params), settings)
    assert job.state == "succeeded", job.error
    doc = json.loads(read(settings, job, "materials.json"))
    cfg = doc["config"]
    assert cfg["scene"]["name"] == "cloth_plane" and cfg["scene"]["resolution"] == [64, 48]
    assert cfg["scene"]["camera"]["origin"] == [0.0, 2.0, 2.4]  # the scene's own
    assert "btdf_fraction" not in cfg and "sizes" not in cfg
    design = FabricScene.model_validate(scene).design()
    for i, (m, aspect) in enumerate(zip(doc["materials"], (1.0, 0.5), strict=True)):
        ref = scene_queries(design, m["design_seed"], 0, 64, tile_aspect=aspect)
        got = shard(settings, job, 2 * i)
        np.testing.assert_array_equal(got["size"], ref.size.astype(np.float32))
        np.testing.assert_array_equal(got["wo"], ref.wo.astype(np.float32))
        np.testing.assert_array_equal(got["wi"], ref.wi.astype(np.float32))
        assert np.all(np.isfinite(got["value"]))
    again = run_in_process(spec(params, force=True), settings)
    assert digests(again) == digests(job)


def test07_each_shard_is_stored_once(settings: Settings) -> None:
    """The store holds the job's artifacts and its manifest and nothing else: no pickled
    copy of a shard's result beside its npz artifact (before, every shard was stored
    twice). Reference: the store's own listing against the job's records."""
    params = {**PARAMS, "patterns": ["plain"], "backend": "numpy"}
    job = run_in_process(spec(params), settings)
    assert job.state == "succeeded", job.error
    store = ArtifactStore(settings.store_dir)
    stored = {digest for digest, _ in store.iter_objects()}
    expected = {a.digest for a in job.artifacts} | {job.manifest_digest}
    assert stored == expected, stored - expected
    assert sum(a.name.endswith(".npz") for a in job.artifacts) == 2  # two shards
