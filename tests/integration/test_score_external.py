"""``score`` of a user's model (``{"external": {"model": REF, "kind": ...}}``) through
``run_in_process``: BRDF-space scoring against a MERL table beside a table candidate, BTF
L1 against a ``generate.btf`` job's slices, cost rows with their runtime.

The models: a plain-numpy class implementing the ExternalModel protocol (``kind``,
``runtime``, ``param_bytes``, ``eval``), loaded through ``models.external.load_external``
wrapped in the test (a JSON ``{"test_model": NAME}`` names one), and Lambertian ONNX
graphs written with ``onnx.helper`` (:mod:`tests.helpers.onnx_models`), loaded by
onnxruntime as an upload would be. Oracles: the test's own SMAPE (Eq. 6 written out below)
and L1 at the documented pairs and texel centres; a Lambertian BTF of the plane's albedo
matches ``generate.btf``'s flat diffuse plane (albedo / pi * cos(theta_i)) to float32
rounding.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

import models.external
from evaluators.metrics.brdf import DEFAULT_PAIRS, PAIRS_SEED, TableSampler, direction_pairs
from evaluators.score.kind import ScoreParams
from jobapi.errors import SpecError
from jobapi.row_sources import StoreSource
from materials.tabulate import tabulate_analytic
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.merl import write_merl
from storage.jobs import Job, JobStore
from tests.helpers import onnx_models

ALBEDO = np.array([0.2, 0.5, 0.8])


class NumpyBrdf:
    """A test-only external BRDF: Lambert ``albedo / pi`` plus a Phong-like lobe
    ``k (cos alpha)^n`` about the mirror direction, in plain numpy."""

    kind = "brdf"
    runtime = "numpy-test"

    def __init__(self, albedo: np.ndarray, k: float = 0.0, n: float = 20.0) -> None:
        self.albedo, self.k, self.n = np.asarray(albedo, np.float64), k, n
        self.param_bytes = 4 * 5

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        mirror = np.stack([-wi[:, 0], -wi[:, 1], wi[:, 2]], axis=1)
        cos_a = np.clip(np.sum(mirror * wo, axis=1), 0.0, 1.0)
        lobe = self.k * cos_a**self.n
        return (self.albedo[None] / math.pi + lobe[:, None]).astype(np.float32)


class NumpyBtf:
    """A test-only external BTF: ``albedo(uv) / pi * cos(theta_i)`` with a stripe of half
    the albedo where ``u mod 1 < 0.25``."""

    kind = "btf"
    runtime = "numpy-test"
    param_bytes = 12

    def eval(self, wi: np.ndarray, wo: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        assert uv is not None
        scale = np.where((uv[:, 0] % 1.0) < 0.25, 0.5, 1.0)
        return (ALBEDO[None] / math.pi * (scale * wi[:, 2])[:, None]).astype(np.float32)


MODELS: dict[str, Any] = {
    "brdf-close": NumpyBrdf(ALBEDO * 1.1, k=0.05),
    "brdf-far": NumpyBrdf(ALBEDO[::-1], k=0.5),
    "btf-stripe": NumpyBtf(),
}


REAL_LOAD = models.external.load_external


def fake_load_external(
    path: Path, kind: str, *, label: str | None = None, runtime: str | None = None
) -> Any:
    """The test's loader: a JSON file ``{"test_model": NAME}`` is one of :data:`MODELS`;
    anything else goes to the real loader."""
    try:
        doc = json.loads(Path(path).read_bytes())
    except ValueError:
        doc = None
    if isinstance(doc, dict) and "test_model" in doc:
        return MODELS[doc["test_model"]]
    return REAL_LOAD(path, kind, label=label, runtime=runtime)


@pytest.fixture
def settings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Settings:
    monkeypatch.setattr(models.external, "load_external", fake_load_external)
    return Settings.from_env({}).with_(data_dir=tmp_path / "data", pool_processes=1)


def stores(settings: Settings) -> tuple[JobStore, ArtifactStore]:
    return JobStore(settings.db_path), ArtifactStore(settings.store_dir)


def upload(path: Path, settings: Settings) -> str:
    jobs, store = stores(settings)
    return f"sha256:{import_file(path, jobs, store).digest}"


def upload_test_model(name: str, tmp_path: Path, settings: Settings) -> str:
    """A ``{"format": <the kind's MLP format>, "test_model": NAME}`` file, stored without the
    upload check (it is no valid MLP file): the submission check reads its format, the
    job's loader (:func:`fake_load_external`) its name."""
    path = tmp_path / f"{name}.json"
    fmt = f"matforge.mlp-{MODELS[name].kind}/1"
    path.write_text(json.dumps({"format": fmt, "test_model": name}))
    jobs, store = stores(settings)
    record = import_file(path, jobs, store, validate=lambda _path, _name: "application/json")
    return f"sha256:{record.digest}"


def lambert_table(tmp_path: Path, settings: Settings) -> str:
    """A MERL table of Lambert ``ALBEDO / pi`` (tabulated with the project's tabulator)."""
    table = tabulate_analytic(
        lambda wi, wo: np.broadcast_to(ALBEDO / math.pi, (len(wi), 3)).copy()
    )[0]
    path = tmp_path / "lambert.binary"
    write_merl(path, table)
    return upload(path, settings)


def run(kind: str, params: dict[str, Any], settings: Settings, seed: int = 0) -> Job:
    job = run_in_process({"kind": kind, "seed": seed, "params": params}, settings)
    assert job.state == "succeeded", job.error
    return job


def read_json(job: Job, name: str, settings: Settings) -> Any:
    (digest,) = [a.digest for a in job.artifacts if a.name == name]
    return json.loads(ArtifactStore(settings.store_dir).read(digest))


def measured_cost(job: Job, settings: Settings) -> Any:
    """The score's measured ``cost`` (its manifest's ``timings.measured``), with a check
    that no artifact holds timings (the same spec gives the same bytes)."""
    assert "cost.json" not in {a.name for a in job.artifacts}
    jobs, store = stores(settings)
    manifest = json.loads(store.read(jobs.get(job.id).manifest_digest))
    return manifest["timings"]["measured"]["cost"]


def job_rows(job: Job, settings: Settings) -> list[Any]:
    from evaluators.score.rows import score_rows

    jobs, store = stores(settings)
    return score_rows(StoreSource(jobs.get(job.id), jobs, store))


def own_smape(f: np.ndarray, g: np.ndarray) -> float:
    """Eq. 6 of the hybrid-BRDF paper, eps 0, 0/0 = 0, mean over pairs and channels."""
    num, den = np.abs(f - g), np.abs(f) + np.abs(g)
    return float(np.mean(np.where(den > 0, 2.0 * num / np.where(den > 0, den, 1.0), 0.0)))


@pytest.mark.slow  # 10^6 pairs through the table lookup (about 25 s on 2 cores)
def test01_external_brdf_against_a_table(tmp_path: Path, settings: Settings) -> None:
    table_ref = lambert_table(tmp_path, settings)
    close = upload_test_model("brdf-close", tmp_path, settings)
    far = upload_test_model("brdf-far", tmp_path, settings)
    job = run(
        "score",
        {
            "reference": table_ref,
            "candidates": {
                "close": {"external": {"model": close, "kind": "brdf"}},
                "far": {"external": {"model": far, "kind": "brdf"}},
                "itself": table_ref,
            },
        },
        settings,
    )
    doc = read_json(job, "metrics.json", settings)
    # The test's own SMAPE at the documented pairs: the reference through the table
    # lookup (the same multilinear lookup a table candidate gets), the model in numpy.
    wi, wo = direction_pairs(DEFAULT_PAIRS, seed=PAIRS_SEED, distribution="cosine")
    from storage.formats.merl import read_merl

    jobs, store = stores(settings)
    table = read_merl(store.path(table_ref.removeprefix("sha256:")), table_ref)
    ref = TableSampler(table, interpolate=True).eval(wi, wo)
    keep = ~np.any(ref < 0, axis=1)
    for label, name in (("close", "brdf-close"), ("far", "brdf-far")):
        mine = MODELS[name].eval(wi[keep].astype(np.float32), wo[keep].astype(np.float32))
        expect = own_smape(ref[keep], mine.astype(np.float64))
        assert doc["metrics"][label]["smape"] == pytest.approx(expect, rel=1e-9, abs=1e-12)
        mae = float(np.mean(np.abs(ref[keep] - mine)))
        assert doc["metrics"][label]["mae"] == pytest.approx(mae, rel=1e-6)
    assert doc["metrics"]["close"]["smape"] < doc["metrics"]["far"]["smape"]
    assert doc["metrics"]["itself"]["smape"] == pytest.approx(0.0, abs=1e-12)
    assert doc["settings"]["candidate_external"] == {"close": close, "far": far}

    cost = measured_cost(job, settings)
    assert set(cost["candidates"]) == {"close", "far"}
    for c in cost["candidates"].values():
        assert c["runtime"] == "numpy-test" and c["ns_per_eval"] > 0
        assert c["bytes_per_network"] == 20 and c["batch"] == 1 << 18
    rows = {(r.candidate, r.metric): r for r in job_rows(job, settings)}
    row = rows[("close", "brdf.smape")]
    assert (
        row.runtime == "numpy-test"
        and row.ns_per_eval == cost["candidates"]["close"]["ns_per_eval"]
    )
    assert row.bytes_per_network == 20 and row.dataset == table_ref
    assert row.config == {"external": {"model": close, "kind": "brdf"}}


def test02_onnx_brdf_through_onnxruntime(tmp_path: Path, settings: Settings) -> None:
    table_ref = lambert_table(tmp_path, settings)
    path = onnx_models.save(onnx_models.lambert_model("brdf"), tmp_path / "lambert.onnx")
    ref = upload(path, settings)
    job = run(
        "score",
        {
            "reference": table_ref,
            "candidates": {"onnx": {"external": {"model": ref, "kind": "brdf"}}},
        },
        settings,
    )
    doc = read_json(job, "metrics.json", settings)
    # The same Lambertian albedo as the table: only the table's float64 round-trip and the
    # model's float32 remain (the table's Lambert is exact at every bin).
    assert doc["metrics"]["onnx"]["smape"] < 1e-6
    cost = measured_cost(job, settings)["candidates"]["onnx"]
    assert cost["runtime"] == "onnxruntime" and cost["ns_per_eval"] > 0
    assert cost["bytes_per_network"] == 12 + 36  # k (1 x 3) and zero (3 x 3) float32


def test03_external_btf_against_slices(tmp_path: Path, settings: Settings) -> None:
    btf = run(
        "generate.btf",
        {
            "surface": {
                "bsdf": {
                    "type": "diffuse",
                    "reflectance": {"type": "rgb", "value": ALBEDO.tolist()},
                }
            },
            "directions": {"preset": "small"},
            "resolution": 8,
            "spp": 16,
        },
        settings,
        seed=1,
    )
    onnx_ref = upload(
        onnx_models.save(onnx_models.lambert_model("btf", tuple(ALBEDO)), tmp_path / "l.onnx"),
        settings,
    )
    stripe = upload_test_model("btf-stripe", tmp_path, settings)
    job = run(
        "score",
        {
            "reference": f"job:{btf.id}",
            "candidates": {
                "lambert": {"external": {"model": onnx_ref, "kind": "btf"}},
                "stripe": {"external": {"model": stripe, "kind": "btf", "uv_scale": 2.0}},
            },
        },
        settings,
    )
    doc = read_json(job, "metrics.json", settings)
    # The test's own L1 over the slices (matforge.datasets, the public reader).
    import matforge.datasets as datasets

    ds = datasets.open(f"job:{btf.id}", data_dir=settings.data_dir)
    arrays = ds.numpy()
    rgb, wi_all = arrays["rgb"].astype(np.float64), arrays["wi"].astype(np.float64)
    n, h, w, _ = rgb.shape
    u = ((np.arange(w) + 0.5) / w * 2.0) % 1.0  # uv_scale 2
    stripe_scale = np.where(u < 0.25, 0.5, 1.0)[None, None, :, None]
    lam = ALBEDO[None, None, None, :] / math.pi * wi_all[:, 2][:, None, None, None]
    mean_abs = float(np.mean(np.abs(rgb)))
    for label, pred in (("lambert", lam), ("stripe", lam * stripe_scale)):
        l1 = float(np.mean(np.abs(np.broadcast_to(pred, rgb.shape) - rgb)))
        # float32 models against float64 sums: a few ulps of the slices' values
        assert doc["metrics"][label]["l1"] == pytest.approx(l1, rel=1e-4, abs=1e-6)
        rel = doc["metrics"][label]["relative_l1"]
        assert rel == pytest.approx(l1 / mean_abs, rel=1e-4, abs=1e-5)
    # The flat plane is exactly Lambertian of that albedo (generate.btf's convention):
    # the ONNX Lambert matches it to float32 rounding.
    assert doc["metrics"]["lambert"]["relative_l1"] < 1e-5
    assert doc["metrics"]["lambert"]["l1"] < doc["metrics"]["stripe"]["l1"]
    assert [c["case"] for c in doc["cases"]["lambert"]] == ["shadowing", "specular", "rest"]
    rows = job_rows(job, settings)
    whole = [r for r in rows if r.candidate == "lambert" and r.material is None]
    assert {r.metric for r in whole} == {"l1", "relative_l1"}
    assert all(r.runtime == "onnxruntime" and r.ns_per_eval and r.ns_per_eval > 0 for r in whole)
    assert all(r.dataset == f"job:{btf.id}" for r in rows)
    assert {r.family for r in rows if r.material is not None} <= {"shadowing", "specular", "rest"}


def test04_forms_refused_at_spec_time() -> None:
    ext = {"external": {"model": "sha256:" + "0" * 64, "kind": "btf"}}
    with pytest.raises(ValidationError, match="slices of a BTF job"):
        ScoreParams.model_validate({"reference": "sha256:" + "1" * 64, "candidates": {"a": ext}})
    with pytest.raises(ValidationError, match="every candidate is an"):
        ScoreParams.model_validate(
            {"reference": "job:" + "2" * 32, "candidates": {"a": ext, "b": "sha256:" + "3" * 64}}
        )
    brdf = {"external": {"model": "sha256:" + "0" * 64, "kind": "brdf"}}
    with pytest.raises(ValidationError, match="one MERL table"):
        ScoreParams.model_validate({"reference": "job:" + "2" * 32, "candidates": {"a": brdf}})
    with pytest.raises(ValidationError, match="uv_scale"):
        bad = {"external": {"model": "sha256:" + "0" * 64, "kind": "brdf", "uv_scale": 2.0}}
        ScoreParams.model_validate({"reference": "sha256:" + "1" * 64, "candidates": {"a": bad}})


def test05_wrong_file_named(tmp_path: Path, settings: Settings) -> None:
    table_ref = lambert_table(tmp_path, settings)
    btf_onnx = upload(
        onnx_models.save(onnx_models.lambert_model("btf"), tmp_path / "b.onnx"), settings
    )
    spec = {
        "kind": "score",
        "seed": 0,
        "params": {
            "reference": table_ref,
            "candidates": {"x": {"external": {"model": btf_onnx, "kind": "brdf"}}},
        },
    }
    # refused before queueing, naming the field, the file and the signature it needs
    with pytest.raises(SpecError) as err:
        run_in_process(spec, settings)
    text = str(err.value)
    assert "params.candidates.x.external.model" in text and btf_onnx in text
    assert "declared kind 'brdf' needs inputs (wi, wo)" in text
