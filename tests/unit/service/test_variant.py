"""``MATFORGE_VARIANT``: the setting, its start-up refusal, the shards' variant, and the rule
that makes it part of a spec's identity only where the bytes depend on it.

Oracles: the settings' own round trip; the variant Mitsuba reports after the edge's start-up
(:func:`service.workers.backend.start_backend`, what a worker runs); the error text a user
sees; sha256 of the canonical spec, with and without the variant, written out here by hand.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import pytest

import materials.backend as backend
from jobapi.errors import BackendUnavailable
from service import kinds
from service.settings import VARIANTS, Settings
from service.specs import REFERENCE_VARIANT, canonical_json, validate_spec
from service.workers.backend import probe_variant, setup_shard_process, start_backend
from service.workers.executors import LocalPoolExecutor

REPO = Path(__file__).resolve().parents[3]
HAS_LLVM19 = Path(backend.DEFAULT_LIBLLVM).is_file()


def _cuda_here() -> bool:
    import drjit as dr

    return backend.cuda_available(dr)


def test01_setting_default_choices_and_round_trip() -> None:
    assert Settings.from_env({}).variant == "auto"
    assert VARIANTS == backend.VARIANT_CHOICES  # service cannot import materials' tuple
    for name in VARIANTS:
        s = Settings.from_env({"MATFORGE_VARIANT": name})
        assert s.variant == name
        assert Settings.from_env(s.to_env()).variant == name  # what a worker is started with
    with pytest.raises(ValueError, match="MATFORGE_VARIANT='optix_rgb' is not one of auto"):
        Settings.from_env({"MATFORGE_VARIANT": "optix_rgb"})
    with pytest.raises(ValueError, match="unknown Mitsuba variant 'optix_rgb'"):
        backend.configure("optix_rgb")


@pytest.mark.skipif(not HAS_LLVM19, reason="needs libLLVM-19 (make setup)")
def test02_explicit_llvm_through_the_setting() -> None:
    before = backend.configured_choice()
    try:
        variant = start_backend(Settings.from_env({"MATFORGE_VARIANT": "llvm_ad_rgb"}))
        mi = backend.load_mitsuba()
        assert variant == mi.variant() == backend.active_variant() == "llvm_ad_rgb"
        import drjit.llvm

        assert backend.jit_backend(mi) is drjit.llvm
        assert type(mi.Float(0.0)).__module__.startswith("drjit.llvm")
    finally:
        backend.configure(before)


def test03_cuda_without_cuda_is_refused_naming_the_setting() -> None:
    if _cuda_here():
        pytest.skip("this machine has CUDA")
    settings = Settings.from_env({"MATFORGE_VARIANT": "cuda_ad_rgb"})
    before = backend.configured_choice()
    try:
        with pytest.raises(BackendUnavailable) as err:
            start_backend(settings)
    finally:
        backend.configure(before)
    msg = str(err.value)
    assert msg.startswith("MATFORGE_VARIANT=cuda_ad_rgb: ") and "no CUDA driver" in msg
    assert backend.active_variant() != "cuda_ad_rgb"  # nothing was switched
    # serve's probe (a child process: the web process never imports Mitsuba) says the same.
    with pytest.raises(BackendUnavailable, match="MATFORGE_VARIANT=cuda_ad_rgb: .*CUDA"):
        probe_variant(settings)


def test04_matforge_run_refuses_before_queueing(tmp_path: Path) -> None:
    if _cuda_here():
        pytest.skip("this machine has CUDA")
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"kind": "render", "params": {"resolution": [8, 8], "spp": 1}}))
    env = {**os.environ, "MATFORGE_VARIANT": "cuda_ad_rgb"}
    proc = subprocess.run(
        [str(REPO / ".venv/bin/matforge"), "run", str(spec), "--data-dir", str(tmp_path)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "MATFORGE_VARIANT=cuda_ad_rgb" in proc.stderr and "CUDA" in proc.stderr
    assert proc.stdout == "" and not (tmp_path / "jobs.sqlite3").exists()  # nothing queued


def _choice_in_shard(_: int) -> str:
    return backend.configured_choice()


def test05_shard_processes_take_the_job_processs_variant() -> None:
    pool = LocalPoolExecutor(2, (setup_shard_process, ("scalar_rgb", backend.DEFAULT_LIBLLVM)))
    try:
        got = dict(pool.map(_choice_in_shard, [0, 1, 2]))
    finally:
        pool.close()
    assert got == {0: "scalar_rgb", 1: "scalar_rgb", 2: "scalar_rgb"}


def _hash(body: dict) -> str:
    return hashlib.sha256(canonical_json(body).encode()).hexdigest()


def test06_variant_joins_the_identity_only_where_it_changes_bytes() -> None:
    kinds.load_builtin()
    render = {"kind": "render", "seed": 2, "params": {"resolution": [8, 8], "spp": 1}}
    ref = validate_spec(render)
    body = json.loads(ref.canonical)
    assert ref.spec_hash == _hash(body)  # no variant: the identity every spec always had
    assert validate_spec(render, variant=REFERENCE_VARIANT).spec_hash == ref.spec_hash
    cuda = validate_spec(render, variant="cuda_ad_rgb")
    assert cuda.spec_hash == _hash({**body, "variant": "cuda_ad_rgb"}) != ref.spec_hash
    assert cuda.canonical == ref.canonical and "variant" not in cuda.document()
    assert validate_spec(render, variant="scalar_rgb").spec_hash not in (
        ref.spec_hash,
        cuda.spec_hash,
    )
    # generate.merl: an analytic source is numpy (no variant); a Mitsuba source is a kernel.
    analytic = {"kind": "generate.merl", "params": {"source": {"analytic": {"model": "lambert"}}}}
    assert (
        validate_spec(analytic, variant="cuda_ad_rgb").spec_hash
        == validate_spec(analytic).spec_hash
    )
    mitsuba = {"kind": "generate.merl", "params": {"source": {"mitsuba": {"type": "diffuse"}}}}
    assert (
        validate_spec(mitsuba, variant="cuda_ad_rgb").spec_hash != validate_spec(mitsuba).spec_hash
    )
    # A torch kind's bytes do not depend on Mitsuba's variant.
    btf = {"kind": "train.btf", "params": {"data": "job:" + "a" * 32, "model": "neumip"}}
    assert validate_spec(btf, variant="cuda_ad_rgb").spec_hash == validate_spec(btf).spec_hash


def test07_every_kind_states_its_rule() -> None:
    """The kinds that render or run Dr.Jit kernels say so (the documented rule)."""
    kinds.load_builtin()
    table = {name: k.variant_bytes for name, k in kinds.all_kinds().items()}
    for name in ("render", "generate.btf", "evaluate.tss"):
        assert table[name] is True, name
    for name in ("generate.merl", "generate.fabric", "select"):
        assert callable(table[name]), name
    for name in ("score", "import.btf", "train.btf", "train.brdf", "train.fabric"):
        assert table[name] is False, name


def test08_the_api_hashes_with_the_servers_variant(tmp_path: Path) -> None:
    """A server whose workers run CUDA queues a render as a new job; one on LLVM (or with
    ``auto`` resolved to LLVM here) finds the spec's old identity."""
    from fastapi.testclient import TestClient

    from service.api import create_app

    render = {"kind": "render", "seed": 3, "params": {"resolution": [8, 8], "spp": 1}}
    kinds.load_builtin()
    hashes = {}
    for variant in ("cuda_ad_rgb", "llvm_ad_rgb"):
        settings = Settings.from_env({}).with_(data_dir=tmp_path / variant, variant=variant)
        with TestClient(create_app(settings)) as client:
            r = client.post("/api/jobs", json=render)
            assert r.status_code == 201, r.text
            hashes[variant] = client.get(f"/api/jobs/{r.json()['id']}").json()["spec_hash"]
    assert hashes["llvm_ad_rgb"] == validate_spec(render).spec_hash
    assert hashes["cuda_ad_rgb"] == validate_spec(render, variant="cuda_ad_rgb").spec_hash
    assert hashes["cuda_ad_rgb"] != hashes["llvm_ad_rgb"]


def test09_serve_refuses_to_start(tmp_path: Path) -> None:
    """``matforge serve`` probes the variant before it starts anything (no web process, no
    worker), and exits 2 naming the setting."""
    if _cuda_here():
        pytest.skip("this machine has CUDA")
    env = {**os.environ, "MATFORGE_VARIANT": "cuda_ad_rgb"}
    proc = subprocess.run(
        [str(REPO / ".venv/bin/matforge"), "serve", "--port", "0", "--data-dir", str(tmp_path)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "MATFORGE_VARIANT=cuda_ad_rgb: " in proc.stderr and "dashboard" not in proc.stderr
    assert not (tmp_path / "scratch").exists()  # nothing was started
