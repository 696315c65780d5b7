"""The lead picture of ``import.btf``, in headless Chromium, as the lead test checks every
kind with smoke params (:func:`tests.e2e.test_dashboard_lead_browser.check_lead`).
``import.btf`` has none (it reads an uploaded folder), so its input is made here by the
project's own code: the slices of a small ``generate.btf`` job written as a slice folder
(:func:`generators.btf.slice_folder.job_slice_folder`), packed and uploaded as a user's
``matforge import`` does. Its job page shows its ``preview.png`` first, at full size; its
compare view shows it with no placeholder. The import itself is checked against the
generated slices (EXR float32: the same values, bit for bit). Screenshot:
``/tmp/matforge-lead-import-btf.png``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from generators.btf.slice_folder import job_slice_folder
from service import kinds
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.btf import parse_index, read_shard
from storage.formats.btf_folder import pack_folder
from storage.jobs import Job, JobStore

from .browser import BROWSER, browser_server, data_settings
from .test_dashboard_lead_browser import check_lead

pytestmark = BROWSER


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    kinds.load_builtin()
    settings = data_settings(tmp_path_factory, "dashboard-lead-import-btf")
    root = settings.data_dir.parent
    spec = {"kind": "generate.btf", "params": kinds.get_kind("generate.btf").smoke}
    generated = run_in_process(spec, settings)
    assert generated.state == "succeeded", generated.error
    store = ArtifactStore(settings.store_dir)
    folder = job_slice_folder(generated.artifacts, store, root / "scan")
    jobs = JobStore(settings.db_path)
    try:
        record = import_file(pack_folder(folder, root / "scan.btf.zip"), jobs, store)
        spec = {"kind": "import.btf", "params": {"archive": f"sha256:{record.digest}"}}
        imported = run_in_process(spec, settings)
        assert imported.state == "succeeded", imported.error
        yield {"data": settings.data_dir, "store": store, "db": jobs, "generated": generated,
               "imported": jobs.get(imported.id), "tmp": root}  # fmt: skip
    finally:
        jobs.close()


server = browser_server("tests.e2e.test_dashboard_browser:gallery_kind")


def _slices(store: ArtifactStore, job: Job, tmp: Path) -> tuple[np.ndarray, ...]:
    """A BTF job's ``wi``, ``wo`` and ``rgb``, all shards, read with the shard reader."""
    digests = {a.name: a.digest for a in job.artifacts}
    tmp.mkdir(parents=True, exist_ok=True)
    parts = []
    for name, _ in parse_index(store.read(digests["btf.json"])).shards:
        (tmp / name).write_bytes(store.read(digests[name]))
        parts.append(read_shard(tmp / name, name))
    return tuple(np.concatenate([getattr(p, k) for p in parts]) for k in ("wi", "wo", "rgb"))


def test_the_folder_imports_the_generated_slices(prepared: dict[str, Any]) -> None:
    """The reference: the generated job's own slices (the folder's source)."""
    store, tmp = prepared["store"], prepared["tmp"]
    want = _slices(store, prepared["generated"], tmp / "want")
    got = _slices(store, prepared["imported"], tmp / "got")
    assert got[2].shape == want[2].shape and len(want[2]) >= 2, (got[2].shape, want[2].shape)
    np.testing.assert_array_equal(got[2], want[2])  # EXR float32 is lossless
    np.testing.assert_allclose(got[0], want[0], atol=2e-6)  # angles stored to 1e-6 degrees
    np.testing.assert_allclose(got[1], want[1], atol=2e-6)


def test_lead_picture_of_import_btf(page: Any, server: str, prepared: dict[str, Any]) -> None:
    job = prepared["imported"]
    assert any(a.name == "preview.png" for a in job.artifacts), [a.name for a in job.artifacts]
    check_lead(page, server, job, prepared["db"])
