"""The rows hooks of the kinds (:attr:`jobapi.kinds.Kind.rows`) over hand-made artifacts:
one row per value, each with the facts of what it measured and its costs."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import pytest

from jobapi.metric_names import declared
from jobapi.rows import JobFacts, ResultRow, RowSource, headline_rows
from service import kinds
from tests.helpers.glint_stats import glint_stats
from tests.helpers.job_documents import (
    brdf_materials,
    brdf_metrics,
    brdf_scores,
    btf_metrics,
    fabric_metrics,
    fabric_stats,
    merl_materials,
    tss_metrics,
    tss_row,
    tss_timing,
)

A, B, C = "a" * 32, "b" * 32, "c" * 32


class FakeSource:
    """A job with given params and artifacts; other jobs by id."""

    def __init__(
        self,
        kind: str,
        params: Mapping[str, Any],
        artifacts: Mapping[str, Any],
        *,
        job_id: str = A,
        seed: int = 0,
        seconds: float | None = 2.0,
        others: Mapping[str, FakeSource] | None = None,
        measured: Mapping[str, Any] | None = None,
    ) -> None:
        self.job = JobFacts(id=job_id, kind=kind, seed=seed, params=params, run_seconds=seconds,
                            measured=measured or {})  # fmt: skip
        self._artifacts, self._others = artifacts, others or {}

    def read(self, name: str) -> Any:
        return self._artifacts.get(name)

    def source(self, ref: str) -> RowSource | None:
        return self._others.get(ref.removeprefix("job:").split("/")[0])


def rows_of(src: FakeSource) -> list[ResultRow]:
    kind = kinds.get_kind(src.job.kind)
    assert kind.rows is not None
    rows = kind.rows(src)
    # each metric is one its kind declares (what metric.<name> columns and --metric accept)
    assert all(declared(kind.metrics, r.metric) for r in rows), {r.metric for r in rows}
    return rows


def by_metric(rows: list[ResultRow], **where: Any) -> dict[str, ResultRow]:
    picked = [r for r in rows if all(getattr(r, k) == v for k, v in where.items())]
    out = {r.metric: r for r in picked}
    assert len(out) == len(picked), "one row per metric expected"
    return out


def test01_score_of_renders_carries_spp_and_time() -> None:
    render = {
        "scene": "cloth_plane",
        "spp": 16,
        "resolution": [64, 64],
        "max_depth": 2,
        "material": {"model": f"job:{C}/model.pt", "fabric": {"pattern": "twill_3x3"}},
    }
    gt = FakeSource(
        "render",
        {**render, "spp": 256, "material": {"fabric": {}}},
        {},
        job_id=B,
        seed=1,
        seconds=30.0,
    )
    net = FakeSource("render", render, {}, job_id=C, seed=2, seconds=1.5)
    metrics = {
        "metrics": {"net16": {"flip": 0.1, "psnr": 30.0, "ssim": None}, "other": {"flip": 0.3}},
        "settings": {"artifact_kind": "image-hdr"},
    }
    score = FakeSource(
        "score",
        {
            "reference": f"job:{B}/image.exr",
            "candidates": {"net16": f"job:{C}/image.exr", "other": "sha256:" + "0" * 64},
        },
        {"metrics.json": metrics},
        others={B: gt, C: net},
        seed=7,
    )
    rows = rows_of(score)
    net_rows = by_metric(rows, candidate="net16")
    # image metrics say their space; a null value is no measurement
    assert set(net_rows) == {"image.flip", "image.psnr"}
    flip = net_rows["image.flip"]
    assert (flip.value, flip.lower_is_better, flip.spp, flip.render_seconds) == (0.1, True, 16, 1.5)
    assert flip.scene == "cloth_plane" and flip.seed == 2 and flip.kind == "score"
    assert flip.config["source"] == "model" and flip.dataset == f"job:{B}/image.exr"
    assert net_rows["image.psnr"].lower_is_better is False
    other = by_metric(rows, candidate="other")["image.flip"]  # not a render: the reference's scene
    assert other.scene == "cloth_plane" and other.spp is None and other.seed == 7


def test02_score_of_a_whole_model_per_material() -> None:
    metrics = {
        "metrics": {"m": {"smape": 0.2}},
        "per_material": {"m": {"gold": {"smape": 0.1}, "blue": {"smape": 0.3}}},
    }
    src = FakeSource(
        "score",
        {"reference": f"job:{B}", "candidates": {"m": {"model": "x"}}},
        {"metrics.json": metrics},
    )
    rows = rows_of(src)
    assert [(r.material, r.value) for r in rows] == [("mean", 0.2), ("gold", 0.1), ("blue", 0.3)]
    assert {r.dataset for r in rows} == {f"job:{B}"}


def test03_train_brdf() -> None:
    gold = brdf_scores("gold", "metal", smape=0.4, smape_floor=0.3, mae=0.1, smape_analytic=0.5)
    metrics = brdf_metrics([gold], smape=0.4, mae=0.1, smape_analytic=0.5)
    info = brdf_materials([("gold", "metal", "train")], width=32, depth=3, latent_dim=4)
    speed = {
        "rows": [
            {"trained": False, "fused_kernel_ns": 1.0},
            {
                "trained": True,
                "fused_kernel_ns": 4.09,
                "fused_ns": 5.26,
                "torch_ns": 50.0,
                "bytes_per_network": 5000,
            },
        ]
    }
    params = {"dataset": f"job:{B}", "preset": "small", "steps": 300}
    artifacts = {"metrics.json": metrics, "materials.json": info}
    # The speed timings are in the manifest (timings.measured.speed); a job run before they
    # moved there has them as a speed.json artifact, and gives the same rows.
    src = FakeSource("train.brdf", params, artifacts, seconds=90.0, measured={"speed": speed})
    legacy = FakeSource("train.brdf", params, {**artifacts, "speed.json": speed}, seconds=90.0)
    assert rows_of(legacy) == rows_of(src)
    assert not [r for r in rows_of(FakeSource("train.brdf", params, artifacts)) if r.ns_per_eval]
    rows = rows_of(src)
    gold = by_metric(rows, material="gold")
    assert set(gold) == {"brdf.smape", "brdf.smape_floor", "brdf.mae", "brdf.smape_analytic"}
    assert gold["brdf.smape_floor"].value == 0.3
    assert gold["brdf.smape"].family == "metal" and gold["brdf.smape"].config["split"] == "train"
    assert gold["brdf.smape"].split == "train"
    mean = by_metric(rows, material="mean")
    assert set(mean) == {"brdf.smape", "brdf.mae", "brdf.smape_analytic"}
    assert {r.split for r in mean.values()} == {"train"}  # no held-out materials
    speed_rows = by_metric(rows, material=None)
    assert {k: r.value for k, r in speed_rows.items()} == {
        "fused_kernel_ns": 4.09,
        "fused_ns": 5.26,
        "torch_ns": 50.0,
    }
    for r in rows:  # one cost per meaning: ns_per_eval is the kernel's time everywhere
        assert (r.candidate, r.ns_per_eval, r.bytes_per_material) == ("hybrid 32x3", 4.09, 44.0)
        assert (r.bytes_per_network, r.train_seconds, r.dataset) == (5000, 90.0, f"job:{B}")


def test03b_train_brdf_held_out_materials_are_the_test_split() -> None:
    """Held-out families: each material's rows say its split (heldout: ``test``), and the
    whole-set rows are the mean of each split, the test one first, never one mean over
    both (which would headline a training error)."""
    mats = [brdf_scores("gold", "metal", smape=0.1), brdf_scores("blue", "paint", "heldout",
                                                                  smape=0.3)]  # fmt: skip
    metrics = brdf_metrics(mats, smape=0.2, mae=0.0)
    metrics["splits"] = {
        "train": brdf_metrics(mats[:1], smape=0.1, mae=0.0)["mean"],
        "heldout": brdf_metrics(mats[1:], smape=0.3, mae=0.0)["mean"],
    }
    info = brdf_materials([("gold", "metal", "train"), ("blue", "paint", "heldout")])
    src = FakeSource("train.brdf", {"dataset": f"job:{B}"},
                     {"metrics.json": metrics, "materials.json": info})  # fmt: skip
    rows = rows_of(src)
    assert by_metric(rows, material="blue")["brdf.smape"].split == "test"
    assert by_metric(rows, material="gold")["brdf.smape"].split == "train"
    means = [(r.split, r.value) for r in rows if r.material == "mean" and r.metric == "brdf.smape"]
    assert means == [("test", 0.3), ("train", 0.1)]
    (head,) = [r for r in headline_rows(rows) if r.metric == "brdf.smape"]
    assert (head.split, head.value) == ("test", 0.3)


def test04_train_fabric_network_and_baseline() -> None:
    mat = {
        "name": "twill-0",
        "pattern": "twill_3x3",
        "queries": 100,
        "loss": 0.5,
        "rgb": {"rel": 0.2, "mse": 0.01},
        "baseline": {"loss": 0.9, "rgb": {"rel": 0.6}},
    }
    doc = fabric_metrics([mat], {"count": 1, "loss": 0.5, "rgb": {"rel": 0.2}})
    rows = rows_of(
        FakeSource("train.fabric", {"dataset": f"job:{B}", "steps": 10}, {"metrics.json": doc})
    )
    net = by_metric(rows, material="twill-0", candidate="network")
    base = by_metric(rows, material="twill-0", candidate="baseline")
    assert {k: r.value for k, r in net.items()} == {"loss": 0.5, "rgb.rel": 0.2, "rgb.mse": 0.01}
    assert {k: r.value for k, r in base.items()} == {"loss": 0.9, "rgb.rel": 0.6}
    assert net["rgb.rel"].family == "twill_3x3" and net["rgb.rel"].lower_is_better is True
    assert set(by_metric(rows, material="mean", candidate="network")) == {"loss", "rgb.rel"}


def test05_train_btf_and_tss() -> None:
    doc = btf_metrics("c2f", l1=0.02, l1_train=0.019, l1_heldout=None, relative_l1=0.1,
                      texture_bytes=1000, network_bytes=200)  # fmt: skip
    rows = by_metric(
        rows_of(
            FakeSource("train.btf", {"data": f"job:{B}", "model": "c2f"}, {"metrics.json": doc})
        )
    )
    assert set(rows) == {"l1", "l1_train", "relative_l1"}
    assert (rows["l1"].bytes_per_material, rows["l1"].bytes_per_network) == (1000, 200)
    row = tss_row(64, 2, flip_mean=0.05, flip_max=0.08, psnr_mean=35.0, psnr_min=None)
    metrics = tss_metrics([row])
    timing = tss_timing({"64/N=2": (0.004, 0.5)})
    tss = by_metric(
        rows_of(
            FakeSource(
                "evaluate.tss",
                {"model": f"job:{C}/model.json"},
                {"metrics.json": metrics, "timing.json": timing},
            )
        )
    )
    assert set(tss) == {"image.flip_mean", "image.flip_max", "image.psnr_mean", "relative_cost"}
    assert tss["image.flip_mean"].ms_per_frame == pytest.approx(4.0)
    flip = tss["image.flip_mean"]
    assert flip.candidate == "64/N=2" and flip.config["interval"] == 2
    # The documents are read typed: a metrics.json of another shape gives no rows, and a
    # timing.json of another shape no costs (the FLIP rows stay).
    params = {"model": f"job:{C}/model.json"}
    assert rows_of(FakeSource("evaluate.tss", params, {"metrics.json": {"rows": [row]}})) == []
    untimed = by_metric(rows_of(FakeSource("evaluate.tss", params, {
        "metrics.json": metrics, "timing.json": {"rows": timing["rows"]}})))  # fmt: skip
    assert set(untimed) == {"image.flip_mean", "image.flip_max", "image.psnr_mean"}
    assert untimed["image.flip_mean"].ms_per_frame is None


def test06_render_and_missing_artifacts() -> None:
    render = FakeSource("render", {"scene": "sphere_env", "spp": 4, "material": {"merl": "x"}}, {})
    (row,) = rows_of(render)
    assert (row.metric, row.value, row.spp, row.config["source"]) == (
        "render_seconds",
        2.0,
        4,
        "merl",
    )
    assert rows_of(FakeSource("render", {}, {}, seconds=None)) == []
    # the render's own time (its manifest's timings.measured) wins over the job's wall time
    own = FakeSource("render", {"scene": "sphere_env", "spp": 4}, {})
    own.job = dataclasses.replace(own.job, measured={"render_seconds": 0.25})
    (row,) = rows_of(own)
    assert (row.value, row.render_seconds) == (0.25, 0.25)
    for kind in ("score", "train.brdf", "train.fabric", "train.btf", "evaluate.tss"):
        assert rows_of(FakeSource(kind, {}, {})) == [], kind


def test07_generators_measure_their_output() -> None:
    glint = glint_stats(total=4096, memory_ratio=0.0625)
    glint["reference"]["bytes"] = 65536
    rows = by_metric(rows_of(FakeSource("generate.glint", {}, {"stats.json": glint})))
    assert {k: r.value for k, r in rows.items()} == {
        "bytes": 4096,
        "reference_bytes": 65536,
        "memory_ratio": 0.0625,
        "precompute_seconds": 0.5,
    }
    assert rows["memory_ratio"].candidate == "isotropic_noise"
    assert rows["memory_ratio"].lower_is_better is True
    # Every row costed with the example's own bytes, its size in config.
    assert {r.bytes_per_material for r in rows.values()} == {4096}
    assert rows["bytes"].config == {"size": 16, "levels": 4, "ndf_resolution": 32, "lobes": 1024}
    # Since timings moved to the manifest, stats.json has no precompute_seconds: the row
    # reads timings.measured.precompute_seconds (above: an older job's stats.json has it).
    del glint["precompute_seconds"]
    timed = FakeSource("generate.glint", {}, {"stats.json": glint},
                       measured={"precompute_seconds": 0.25})  # fmt: skip
    rows = by_metric(rows_of(timed))
    assert rows["precompute_seconds"].value == 0.25 and rows["bytes"].value == 4096
    assert "precompute_seconds" not in by_metric(
        rows_of(FakeSource("generate.glint", {}, {"stats.json": glint}))
    )
    # A stats.json of another shape is not read (no guessing from a partial document).
    partial = {"example": {"size": 16}, "bytes": {"total": 4096}}
    assert rows_of(FakeSource("generate.glint", {}, {"stats.json": partial})) == []
    btf = {
        "count": 10,
        "resolution": [32, 32],
        "spp": 16,
        "stderr": {"mean": 0.01, "relative": 0.05},
    }
    rows = by_metric(rows_of(FakeSource("generate.btf", {"spp": 16}, {"btf.json": btf})))
    assert {k: (r.value, r.spp) for k, r in rows.items()} == {
        "stderr_mean": (0.01, 16),
        "stderr_relative": (0.05, 16),
    }
    merl = merl_materials([{"name": "gold", "family": "metal", "source": {"mitsuba": {}},
                            "tabulation": {"max_rel_error": 0.001, "bins": 90}}])  # fmt: skip
    rows = by_metric(rows_of(FakeSource("generate.merl", {}, {"materials.json": merl})))
    assert {k: r.value for k, r in rows.items()} == {
        "tabulation.max_rel_error": 0.001,
        "tabulation.bins": 90,
    }
    stats = fabric_stats("drjit", samples_per_second=8.0e6, seconds=3.0)
    rows = by_metric(rows_of(FakeSource("generate.fabric", {}, {"stats.json": stats})))
    assert rows["samples_per_second"].lower_is_better is False
    assert rows["seconds"].value == 3.0 and rows["seconds"].candidate == "drjit"
    # A job made since timings moved to the manifest: stats.json has the counts and the
    # backend, timings.measured.throughput the times.
    counts = fabric_stats("numpy")
    throughput = {"seconds": 2.0, "samples_per_second": 1.2e7}
    src = FakeSource("generate.fabric", {}, {"stats.json": counts},
                     measured={"throughput": throughput})  # fmt: skip
    rows = by_metric(rows_of(src))
    assert {k: (r.value, r.candidate) for k, r in rows.items()} == {
        "samples_per_second": (1.2e7, "numpy"),
        "seconds": (2.0, "numpy"),
    }


def test08_glint_renders_carry_their_memory() -> None:
    """A score of glint renders: each candidate's ``bytes_per_material`` from first
    principles (the tiny example's ``stats.json`` total; one 32-byte lobe per exported texel
    for Yan; two float32 for the smooth GGX; a clearcoat's added) and its method and example
    size in ``config``."""
    data = FakeSource(
        "generate.glint",
        {},
        {"stats.json": glint_stats(size=16, total=5000)},
        job_id=C,
    )

    def render(job_id: str, glint: dict[str, Any], seconds: float) -> FakeSource:
        params = {"scene": "bent_quad", "spp": 64, "material": {"glint": glint}}
        return FakeSource("render", params, {}, job_id=job_id, seconds=seconds, others={C: data})

    d, e, f, g = "d" * 32, "e" * 32, "f" * 32, "0" * 32
    ref = f"job:{C}"
    yan = {"data": ref, "method": "yan", "texels_per_uv": 100.5, "oversample": 2}
    coat = {"data": ref, "method": "smooth_ggx"}
    renders = {
        d: render(d, {"data": ref, "method": "tiny_example", "texels_per_uv": 256}, 2.0),
        e: render(e, yan, 30.0),
        f: render(f, {"data": ref, "method": "smooth_ggx"}, 1.0),
        g: render(g, {"data": ref, "method": "tiny_example", "clearcoat": coat}, 3.0),
    }
    names = {d: "tiny", e: "yan", f: "smooth", g: "coated"}
    score = FakeSource(
        "score",
        {
            "reference": f"job:{e}/image.exr",
            "candidates": {names[j]: f"job:{j}/image.exr" for j in renders},
        },
        {"metrics.json": {"metrics": {n: {"flip": 0.1} for n in names.values()}}},
        others=renders,
        job_id=B,
    )
    rows = {r.candidate: r for r in rows_of(score)}
    yan_side = 101 * 2  # ceil(texels_per_uv) texels, each exported at 2 x 2
    assert {c: r.bytes_per_material for c, r in rows.items()} == {
        "tiny": 5000,
        "yan": yan_side * yan_side * 32,
        "smooth": 8,
        "coated": 5008,
    }
    assert (rows["tiny"].config["method"], rows["tiny"].config["example"]) == ("tiny_example", 16)
    assert rows["coated"].config["clearcoat"] == "smooth_ggx"
    assert (rows["yan"].render_seconds, rows["yan"].spp) == (30.0, 64)
    (own,) = rows_of(renders[f])  # the render's own row carries it too
    assert (own.metric, own.bytes_per_material, own.config["method"]) == (
        "render_seconds",
        8,
        "smooth_ggx",
    )
    # Without its data job (not found), a tiny example's memory is unknown, not zero.
    lost = render(d, {"data": f"job:{A}", "method": "tiny_example"}, 2.0)
    (row,) = rows_of(lost)
    assert row.bytes_per_material is None and row.config["example"] is None


def test11_a_brdf_mae_and_an_image_mae_are_two_columns() -> None:
    """The batch methods table (``/compare?batch=``, ``results --pivot``) of a demo-like
    batch: a hybrid's BRDF-space MAE (1/sr) and a render's image MAE were one ``mae``
    column, the hybrid marked best. Through the kinds' rows hooks they are two columns, and
    neither has a best across the two units."""
    from service.results_pivot import pivot

    image = FakeSource(
        "score",
        {"reference": "sha256:" + "1" * 64, "candidates": {"rougher": "sha256:" + "2" * 64}},
        {
            "metrics.json": {
                "metrics": {"rougher": {"flip": 0.1, "mae": 0.0358}},
                "settings": {"artifact_kind": "image-hdr"},
            }
        },  # fmt: skip
    )
    gold = brdf_scores("gold", "metal", smape=0.07, mae=0.003472)
    brdf = FakeSource(
        "train.brdf",
        {"dataset": f"job:{B}"},
        {
            "metrics.json": brdf_metrics([gold], smape=0.07, mae=0.003472),
            "materials.json": brdf_materials([("gold", "metal", "train")]),
        },  # fmt: skip
        job_id=C,
    )
    rows = [r.document() for r in rows_of(image) + rows_of(brdf)]
    doc = pivot(rows)
    names = [c["name"] for c in doc["columns"]]
    assert "mae" not in names and {"brdf.mae", "image.mae"} <= set(names)
    assert doc["cells"]["rougher"]["image.mae"]["mean"] == pytest.approx(0.0358)
    assert doc["cells"]["hybrid 32x3 (train)"]["brdf.mae"]["mean"] == pytest.approx(0.003472)
    assert "image.mae" not in doc["cells"]["hybrid 32x3 (train)"]
    assert "brdf.mae" not in doc["best"] and "image.mae" not in doc["best"]  # one method each
