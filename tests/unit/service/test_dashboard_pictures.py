"""How the job page orders and labels pictures (issue 14 §4), from the kinds' figures:
generate.fabric's preview first (the lead picture), generate.merl's slices with axes."""

from __future__ import annotations

import pytest

from service import kinds
from service.routes.dashboard import breakable, picture_views
from storage.jobs import ArtifactRecord


def png(name: str) -> ArtifactRecord:
    return ArtifactRecord(name=name, digest="0" * 64, size=1, media_type="image/png")


def test01_fabric_preview_leads() -> None:
    kinds.load_builtin()
    arts = [png("a_map.png"), png("preview.png"), png("flip_x.png")]
    images = picture_views(arts, "generate.fabric")
    assert [i["name"] for i in images] == ["preview.png", "a_map.png", "flip_x.png"]
    assert [i["group"] for i in images] == ["lead", "image", "flip"]
    assert "Fig. 2" in images[0]["note"]
    plain = picture_views(arts, "no.such.kind")  # an unregistered kind: names in order, no lead
    assert [i["group"] for i in plain] == ["image", "image", "flip"]


@pytest.mark.parametrize("kind", ["generate.fabric", "generate.glint", "generate.btf"])
def test01b_generators_preview_leads(kind: str) -> None:
    """README: every kind's lead picture comes first, at full size (the ``lead`` group is
    the one job.html draws full width); alphabetical order would put ``a_map.png`` first."""
    kinds.load_builtin()
    images = picture_views([png("a_map.png"), png("preview.png")], kind)
    assert [(i["name"], i["group"]) for i in images] == [
        ("preview.png", "lead"),
        ("a_map.png", "image"),
    ]
    assert images[0]["note"]


#: Picture kinds that declare no lead picture, and why (every other one must declare one).
NO_LEAD = {
    "score": "its pictures are FLIP maps under one colour bar; its reference and candidates "
    "come first, as the Inputs section (the compare view's main pictures)",
    "generate.merl": "one half/difference slice per material, all equal: a gallery of plots "
    "with labelled axes, enlarged with square pixels",
}
PICTURES = ("*.png", "*.exr")


def _pictures(kind: object) -> list[str]:
    import fnmatch

    arts = getattr(kind, "artifacts", ())
    return [a for a in arts if any(fnmatch.fnmatch(a, p) for p in PICTURES)]


def test01c_every_picture_kind_declares_its_lead() -> None:
    """README: the lead picture comes first, at full size, for every kind. Every registered
    kind that writes a picture declares one lead figure on its ``Kind`` (next to the kind,
    not a list here), matching one of its picture artifacts, which then sorts first."""
    import fnmatch

    kinds.load_builtin()
    found = {}
    for kind in kinds.all_kinds().values():
        pics = _pictures(kind)
        if not pics:
            continue
        leads = [f for f in kind.figures if f.lead]
        found[kind.name] = [f.pattern for f in leads]
        if kind.name in NO_LEAD:
            assert not leads, (kind.name, "declares a lead now: drop it from NO_LEAD")
            continue
        assert len(leads) == 1, (kind.name, leads)
        lead = leads[0]
        named = [a for a in pics if fnmatch.fnmatchcase(a, lead.pattern)]
        assert named, (kind.name, lead.pattern, pics)
        assert lead.caption, kind.name
        others = [png(a) for a in pics if a not in named] + [png("a_first.png")]
        media = "image/x-exr" if named[0].endswith(".exr") else "image/png"
        record = ArtifactRecord(name=named[0], digest="1" * 64, size=1, media_type=media)
        images = picture_views([*others, record], kind.name)
        assert (images[0]["name"], images[0]["group"]) == (named[0], "lead"), kind.name
    assert {"render", "train.brdf", "train.btf", "train.fabric", "select", "evaluate.tss",
            "report.pareto", "report.brdf", "report.stability"} <= set(found)  # fmt: skip
    assert set(NO_LEAD) <= set(found), "an exception for a kind without pictures"


def test02_merl_slices_have_labelled_axes() -> None:
    kinds.load_builtin()
    (image,) = picture_views([png("gold.png")], "generate.merl")
    assert image["x"].label.startswith("θh") and (image["x"].start, image["x"].end) == (
        "0°",
        "90°",
    )
    assert image["y"].label == "θd" and image["group"] == "image"


def test03_column_names_break_after_dots() -> None:
    assert str(breakable("baseline.rgb.rel")) == "baseline.<wbr>rgb.<wbr>rel"
    assert str(breakable("<b>.x")) == "&lt;b&gt;.<wbr>x"


def test04_inputs_are_the_pictures_params_refer_to(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A score's reference and candidates show on its page, linked to their jobs."""
    from service.routes.dashboard import input_pictures
    from storage.jobs import JobStore

    jobs = JobStore(tmp_path / "jobs.sqlite3")
    made, _ = jobs.submit(kind="render", name=None, seed=0, spec_hash="a" * 64, spec={})
    claimed = jobs.claim("t:1", 30.0, job_id=made.id)
    assert claimed is not None and claimed.lease_token
    exr = ArtifactRecord(name="image.exr", digest="1" * 64, size=1, media_type="image/x-exr")
    assert jobs.complete(made.id, claimed.lease_token, [exr], "2" * 64)
    jobs.record_upload("3" * 64, "mine.png", "image/png", 1)
    params = {
        "reference": f"job:{made.id}/image.exr",
        "candidates": {"mine": "sha256:" + "3" * 64, "gone": "sha256:" + "4" * 64},
        "metrics": ["flip"],
    }
    score, _ = jobs.submit(
        kind="score", name=None, seed=0, spec_hash="b" * 64, spec={"params": params}
    )
    got = input_pictures(jobs.get(score.id), jobs)
    assert [(i["param"], i["name"], i["job"]) for i in got] == [
        ("reference", "image.exr", made.id),
        ("candidates.mine", "mine.png", None),
    ]
    assert got[0]["src"] == f"/api/artifacts/{'1' * 64}/preview.png"
