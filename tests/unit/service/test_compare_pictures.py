"""The compare view's pictures by role (issue 26 §2): derived once on the server from a
job's spec and artifacts, not from file names in the page; and the inverse of the magma
colouring that gives a FLIP map's value under the cursor."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evaluators.metrics.tonemap import magma, magma_table, magma_values
from service import kinds
from service.compare_pictures import compare_views, job_pictures
from storage.jobs import ArtifactRecord, JobStore


def _finished(jobs: JobStore, kind: str, spec: dict, arts: list[ArtifactRecord], h: str) -> str:
    made, _ = jobs.submit(kind=kind, name=None, seed=0, spec_hash=h * 64, spec=spec)
    claimed = jobs.claim("t:1", 30.0, job_id=made.id)
    assert claimed is not None and claimed.lease_token
    assert jobs.complete(made.id, claimed.lease_token, arts, "f" * 64)
    return made.id


def _rec(name: str, digit: str) -> ArtifactRecord:
    exr = name.endswith(".exr")
    media = "image/x-exr" if exr else "image/png"
    return ArtifactRecord(name=name, digest=digit * 64, size=1, media_type=media)


def test01_roles_of_a_score_job_and_a_render(tmp_path: Path) -> None:
    kinds.load_builtin()
    jobs = JobStore(tmp_path / "jobs.sqlite3")
    render = _finished(jobs, "render", {}, [_rec("image.exr", "1")], "a")
    other = _finished(jobs, "render", {}, [_rec("image.exr", "2")], "b")
    params = {
        "reference": f"job:{render}/image.exr",
        "candidates": {"gold16": f"job:{other}/image.exr", "gone": "sha256:" + "9" * 64},
    }
    arts = [_rec("flip_gold16.png", "3"), _rec("flip_gone.png", "4")]
    score = _finished(jobs, "score", {"params": params}, arts, "c")
    got = job_pictures(jobs.get(score), jobs)
    roles = [(p["role"], p["label"], p["name"], p["values"]) for p in got["pictures"]]
    assert roles == [
        ("reference", "reference", "image.exr", "linear"),
        ("candidate", "gold16", "image.exr", "linear"),
        ("error", "gold16", "flip_gold16.png", "magma"),
        ("error", "gone", "flip_gone.png", "magma"),  # its input is gone; its map is not
    ]
    # a score job's main pictures: its reference and candidates (each a panel)
    assert got["main"] == ["reference:reference", "candidate:gold16"]
    assert got["pictures"][0]["pixels"] == f"/api/artifacts/{'1' * 64}/pixels?values=linear"
    assert got["pictures"][2]["src"] == f"/api/artifacts/{'3' * 64}"
    # a render: its one picture, image.exr, is the kind's declared lead and its main one
    plain = job_pictures(jobs.get(render), jobs)
    assert plain["main"] == ["lead:image.exr"]
    panels = [{"pictures": got["pictures"]}, {"pictures": plain["pictures"]}]
    assert [v["key"] for v in compare_views(panels)] == ["main", "errors", "diff", "image.exr"]
    # the fabric kind's lead picture leads, as on its job page
    fabric = _finished(
        jobs, "generate.fabric", {}, [_rec("a_map.png", "5"), _rec("preview.png", "6")], "d"
    )
    assert job_pictures(jobs.get(fabric), jobs)["main"] == ["lead:preview.png"]
    assert [v["key"] for v in compare_views([{"pictures": plain["pictures"]}])] == [
        "main",
        "image.exr",
    ]  # no error maps, no candidates: no such views


def test02_magma_values_inverts_magma() -> None:
    """Reference: ``magma`` itself (matplotlib's table, index ``round(255 v)``): colouring
    then reading back gives ``v`` to the table step, for every entry and between them."""
    table = magma_table()
    assert len({tuple(c) for c in table}) == 256  # every entry distinct: invertible
    v = np.linspace(0.0, 1.0, 1001).reshape(7, 143)
    back = magma_values(magma(v))
    assert back.shape == v.shape and back.dtype == np.float32
    assert float(np.abs(back - v).max()) <= 0.5 / 255 + 1e-6
    # as read_png gives it (floats in [0, 1]), and a colour off the table: its nearest entry
    as_float = magma(v).astype(np.float32) / 255.0
    np.testing.assert_allclose(magma_values(as_float), back, atol=0)
    off = (table[128].astype(np.int32) + 1).clip(0, 255).astype(np.uint8)
    assert abs(float(magma_values(off[None, None, :])[0, 0]) - 128 / 255) <= 1.5 / 255
