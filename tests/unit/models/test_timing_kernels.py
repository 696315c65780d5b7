"""The kernels of a timing pass (:mod:`models.timing_kernels`) on a real Mitsuba variant:
each evaluates what it names on the pass's batch (checked against something we did not
write: Mitsuba's own BSDF probed independently, an ONNX Lambertian's albedo / pi), and a
short pass over them gives finite costs relative to the reference kernel."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from models import timing_kernels as tk
from models.timing import timing_pass
from tests.helpers.brdf_models import make_model
from tests.helpers.mitsuba_probes import mitsuba_brdf

BATCH = 4096


@pytest.fixture(scope="module")
def mi():  # type: ignore[no-untyped-def]
    from materials.backend import load_mitsuba

    return load_mitsuba()


def test01_reference_is_mitsubas_roughconductor(mi) -> None:  # type: ignore[no-untyped-def]
    q = tk.query_batch(mi, BATCH)
    got = np.array(tk.reference_kernel(q).run(), np.float64).T
    want = mitsuba_brdf(mi, tk.REFERENCE_BSDF, q.wi, q.wo) * q.wo[:, 2:3]
    # the same float32 evaluation twice: agreement to float32 rounding of the cosine
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    assert np.all(np.isfinite(got)) and got.max() > 0


def test02_batch_is_the_cost_batch(mi) -> None:  # type: ignore[no-untyped-def]
    from models.external.cost import cost_batch

    q = tk.query_batch(mi, BATCH)
    wi, wo, _ = cost_batch("brdf", BATCH)
    assert np.array_equal(q.wi, wi) and np.array_equal(q.wo, wo)
    assert q.uv.shape == (BATCH, 2) and q.size == BATCH


def test03_onnx_kernel_evaluates_the_model(mi, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("onnxruntime")
    from models.external import load_external
    from tests.helpers.onnx_models import ALBEDO, lambert_model, save

    model = load_external(save(lambert_model("brdf"), tmp_path / "l.onnx"), "brdf")
    q = tk.query_batch(mi, BATCH)
    k = tk.external_kernel("mine", q, model)
    assert k.runtime == "onnxruntime" and k.evals == BATCH
    out = np.asarray(k.run())
    np.testing.assert_allclose(out, np.broadcast_to(np.array(ALBEDO) / np.pi, out.shape),
                               rtol=1e-6)  # fmt: skip


def test04_a_pass_over_real_kernels(mi) -> None:  # type: ignore[no-untyped-def]
    q = tk.query_batch(mi, BATCH)
    doc = make_model("hybrid", 16, 2, 4)
    kernels = [
        tk.reference_kernel(q),
        tk.builtin_brdf_kernel("hybrid 16x2", q, doc, doc["materials"][0]["name"]),
    ]
    out = np.array(kernels[1].run(), np.float64)
    assert out.shape == (3, BATCH) and np.all(np.isfinite(out))
    rec = timing_pass(kernels, reference=tk.REFERENCE, repeats=5, threads=2,
                      runtimes=tk.runtime_versions(mi))  # fmt: skip
    for name in ("reference", "hybrid 16x2"):
        c = rec["costs"][name]
        d = c["distribution"]
        assert d["n"] == 5 and 0 < d["min"] <= d["median"] <= d["max"]
        assert c["relative"]["median"] > 0
    assert rec["costs"]["hybrid 16x2"]["runtime"] == "drjit-fused"
    assert rec["costs"]["reference"]["runtime"] == "mitsuba"
    assert rec["machine"]["runtimes"]["mitsuba_variant"] == mi.variant()


def test05_scalar_variant_refused() -> None:
    class Scalar:
        @staticmethod
        def variant() -> str:
            return "scalar_rgb"

    with pytest.raises(ValueError, match="vectorised Mitsuba variant"):
        tk.query_batch(Scalar, BATCH)  # type: ignore[arg-type]


def test06_frozen_kernels_replay_what_tracing_computes(mi, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """A frozen kernel's replays equal the traced computation on the same batch: the
    built-in model against :func:`models.brdf.fused.model_brdf` traced directly, a user's
    MLP file against its own numpy evaluation (float64, so float32 tolerance)."""
    import torch

    import matforge.export
    from models.brdf.fused import bake_material, model_brdf
    from models.external import load_external

    q = tk.query_batch(mi, BATCH)
    doc = make_model("hybrid", 16, 2, 4)
    name = doc["materials"][0]["name"]
    k = tk.builtin_brdf_kernel("h", q, doc, name)
    traced = np.array(model_brdf(mi, bake_material(doc, name), q.wi_d, q.wo_d))
    for _ in range(3):  # record, then replays
        np.testing.assert_array_equal(np.array(k.run()), traced)
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(6, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3))
    path = matforge.export.brdf_mlp(net, tmp_path / "mine.json", output_activation="exp")
    model = load_external(path, "brdf")
    ext = tk.external_kernel("mine", q, model)
    assert ext.runtime == "drjit-fused"
    want = model.eval(q.wi, q.wo)
    for _ in range(3):
        got = np.array(ext.run(), np.float64).T
        np.testing.assert_allclose(got, want, rtol=2e-5, atol=1e-6)  # float32 kernel


def test07_frozen_with_textures_held_by_the_model(mi) -> None:  # type: ignore[no-untyped-def]
    """A kernel that reads Dr.Jit arrays its model object holds (a latent texture) replays
    what tracing computes: the arrays enter the frozen call as an input."""
    import drjit as dr

    class Textured:
        def __init__(self) -> None:
            self.tex = [mi.Float(np.linspace(0.0, 1.0, 64, dtype=np.float32))]
            self.scale = 2.0

        def eval(self, uv):  # type: ignore[no-untyped-def]
            i = mi.UInt32(dr.clip(uv[0] * 64.0, 0.0, 63.0))
            return dr.gather(mi.Float, self.tex[0], i) * self.scale

    @dataclass
    class Holder:  # as models.btf.fused keeps a texture's channels
        channels: list[Any]
        size: int

    class InDataclass(Textured):
        def __init__(self) -> None:
            super().__init__()
            self.held = Holder(list(self.tex), 64)

        def eval(self, uv):  # type: ignore[no-untyped-def]
            i = mi.UInt32(dr.clip(uv[0] * self.held.size, 0.0, 63.0))
            return dr.gather(mi.Float, self.held.channels[0], i) * self.scale

    q = tk.query_batch(mi, BATCH)
    for obj in (Textured(), InDataclass()):
        want = np.array(obj.eval(q.uv_d))
        run = tk.frozen(obj.eval, q.uv_d, state=obj)
        for _ in range(3):
            np.testing.assert_array_equal(np.array(run()), want)
