"""``score`` of MERL tables in BRDF space, through ``run_in_process`` and real stores.

Tables come from the project's own tabulation of Mitsuba's ``roughconductor`` (GGX). Oracles:
a table scored against itself has SMAPE 0 and MAE 0; SMAPE and MAE grow with the roughness
gap; both equal a direct numpy computation over the documented pairs (direct
``halfdiff.lookup`` of the tables, Eq. 6 written out here); the settings record the pairs;
mixing images and tables, and metrics of the other kind, fail the job with a clear error.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from evaluators.metrics.brdf import DEFAULT_PAIRS, PAIRS_SEED, direction_pairs
from materials import halfdiff as hd
from materials.tabulate import tabulate_mitsuba
from service.settings import Settings
from service.submission import import_file, run_in_process
from storage.artifacts import ArtifactStore
from storage.formats.exr import write_exr
from storage.formats.merl import MerlTable, write_merl
from storage.jobs import JobStore
from tests.helpers.score_jobs import metrics_json, run_score

ALPHAS = (0.2, 0.25, 0.35)


@pytest.fixture(scope="module")
def ggx_tables() -> dict[float, MerlTable]:
    """MERL tables of Mitsuba's roughconductor (default IOR) at each roughness of ALPHAS."""
    return {a: tabulate_mitsuba({"type": "roughconductor", "alpha": a})[0] for a in ALPHAS}


def upload_table(
    table: MerlTable, name: str, tmp_path: Path, jobs: JobStore, store: ArtifactStore
) -> str:
    path = tmp_path / name
    write_merl(path, table)
    record = import_file(path, jobs, store)
    assert record.media_type == "application/x-merl-binary"
    return f"sha256:{record.digest}"


def direct_scores(ref: MerlTable, *cands: MerlTable) -> tuple[list[tuple[float, float]], int]:
    """``[(SMAPE, MAE)]`` per candidate and the excluded count, written out (Eq. 6) over the
    documented pairs with direct multilinear lookups."""
    wi, wo = direction_pairs(DEFAULT_PAIRS, seed=PAIRS_SEED, distribution="cosine")
    f = hd.lookup(ref.rgb, wi, wo, interpolate=True)
    keep = np.all(f >= 0, axis=1)
    f, wi, wo = f[keep], wi[keep], wo[keep]
    out = []
    for cand in cands:
        g = hd.lookup(cand.rgb, wi, wo, interpolate=True)
        g = np.where(g < 0, 0.0, g)
        den = np.abs(f) + np.abs(g)
        terms = np.where(den > 0, np.abs(f - g) / np.where(den > 0, den, 1.0), 0.0)
        out.append((2.0 * float(terms.mean()), float(np.abs(f - g).mean())))
    return out, int(np.sum(~keep))


@pytest.mark.slow
def test01_tables_scored_in_brdf_space(
    ggx_tables: dict[float, MerlTable],
    tmp_path: Path,
    settings: Settings,
    jobs: JobStore,
    store: ArtifactStore,
) -> None:
    refs = {
        a: upload_table(t, f"ggx_{a}.binary", tmp_path, jobs, store) for a, t in ggx_tables.items()
    }
    params = {
        "reference": refs[0.2],
        "candidates": {"self": refs[0.2], "a025": refs[0.25], "a035": refs[0.35]},
    }
    start = time.perf_counter()
    doc = metrics_json(run_score(params, settings), store)
    print(f"score of 3 candidates over 10^6 pairs: {time.perf_counter() - start:.2f} s")
    print(json.dumps(doc["metrics"]))
    assert doc["reference"] == refs[0.2]
    rows = doc["metrics"]
    assert all(set(row) == {"smape", "mae"} for row in rows.values())  # default: all that apply
    assert rows["self"] == {"smape": 0.0, "mae": 0.0}
    assert 0.0 < rows["a025"]["smape"] < rows["a035"]["smape"] <= 2.0
    assert 0.0 < rows["a025"]["mae"] < rows["a035"]["mae"]
    direct, excluded = direct_scores(ggx_tables[0.2], ggx_tables[0.25], ggx_tables[0.35])
    for label, (s, m) in zip(("a025", "a035"), direct, strict=True):
        assert rows[label]["smape"] == pytest.approx(s, rel=1e-12)
        assert rows[label]["mae"] == pytest.approx(m, rel=1e-12)

    st = doc["settings"]
    assert st["artifact_kind"] == "merl"
    assert (st["pairs"], st["seed"], st["distribution"]) == (10**6, PAIRS_SEED, "cosine")
    assert st["excluded_pairs"] == excluded and st["scored_pairs"] == 10**6 - excluded
    assert st["interpolation"].startswith("multilinear")
    assert st["candidate_missing_pairs"] == {"self": 0, "a025": 0, "a035": 0}
    assert st["smape"]["eps"] == 0.0 and st["smape"]["range"] == [0.0, 2.0]

    # One metric on request; the job's seed does not move the pairs.
    one = {**params, "candidates": {"a025": refs[0.25]}, "metrics": ["mae"]}
    again = run_in_process({"kind": "score", "seed": 9, "params": one}, settings)
    assert metrics_json(again, store)["metrics"] == {"a025": {"mae": rows["a025"]["mae"]}}


@pytest.mark.slow
def test02_missing_reference_data_is_excluded_and_counted(
    ggx_tables: dict[float, MerlTable],
    tmp_path: Path,
    settings: Settings,
    jobs: JobStore,
    store: ArtifactStore,
) -> None:
    holed = ggx_tables[0.2].rgb.copy()
    holed[:, 45:] = -1.0  # no data for theta_d >= 45 degrees
    ref = upload_table(MerlTable(holed), "holed.binary", tmp_path, jobs, store)
    full = upload_table(ggx_tables[0.2], "full.binary", tmp_path, jobs, store)
    doc = metrics_json(run_score({"reference": ref, "candidates": {"full": full}}, settings), store)
    _, excluded = direct_scores(MerlTable(holed))
    assert 0 < excluded < DEFAULT_PAIRS and doc["settings"]["excluded_pairs"] == excluded
    # Where both have data they agree; the interpolated boundary bins differ a little.
    assert doc["metrics"]["full"]["smape"] < 0.05

    # The other way round, the candidate's holes count as zero: SMAPE terms of 1.
    swapped = run_score({"reference": full, "candidates": {"holed": ref}}, settings)
    doc = metrics_json(swapped, store)
    assert doc["settings"]["excluded_pairs"] == 0
    assert doc["settings"]["candidate_missing_pairs"]["holed"] > 0
    [(s, m)], _ = direct_scores(ggx_tables[0.2], MerlTable(holed))
    assert doc["metrics"]["holed"] == {"smape": pytest.approx(s), "mae": pytest.approx(m)}
    assert doc["metrics"]["holed"]["smape"] > 0.2


def test03_mixed_kinds_and_foreign_metrics_fail_clearly(
    ggx_tables: dict[float, MerlTable],
    tmp_path: Path,
    settings: Settings,
    jobs: JobStore,
    store: ArtifactStore,
) -> None:
    table = upload_table(ggx_tables[0.2], "ggx.binary", tmp_path, jobs, store)
    write_exr(tmp_path / "img.exr", np.full((8, 8, 3), 0.5, dtype=np.float32))
    image = f"sha256:{import_file(tmp_path / 'img.exr', jobs, store).digest}"
    cases = [
        (
            {"reference": table, "candidates": {"img": image}},
            "candidate 'img' is an EXR (HDR) image but the reference is a MERL BRDF table",
        ),
        (
            {"reference": image, "candidates": {"tab": table}},
            "candidate 'tab' is a MERL BRDF table but the reference is an EXR (HDR) image",
        ),
        (
            {"reference": table, "candidates": {"a": table}, "metrics": ["smape", "ssim"]},
            "metrics: metric 'ssim' does not apply to a MERL BRDF table; use smape, mae",
        ),
        (
            {"reference": image, "candidates": {"a": image}, "metrics": ["smape"]},
            "metric 'smape' does not apply to an EXR (HDR) image; use flip, psnr, ssim, mae, mse",
        ),
        (
            {"reference": table, "candidates": {"a": table}, "exposure": {"start": 0.0}},
            "exposure: applies to HDR-FLIP only",
        ),
    ]
    for params, message in cases:
        job = run_score(params, settings)
        assert job.state == "failed" and job.error is not None
        assert message in job.error, job.error
