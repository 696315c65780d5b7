"""``generators.fabric.params``: presets, resolution of explicit fields, the material plan,
and the names :mod:`generators.fabric.kind` re-exports from it."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

import generators.fabric.kind as fabric
import generators.fabric.params as fp
from materials.fabric.patterns import TRAINING_PATTERNS


def test01_reexports_are_the_same_objects() -> None:
    for name in (
        "FabricGenParams",
        "FabricPreset",
        "PRESETS",
        "REPLICATES",
        "MAX_MATERIALS",
        "MAX_QUERIES",
        "Resolved",
        "plan_sets",
    ):
        assert getattr(fabric, name) is getattr(fp, name), name
    assert set(fabric.__all__) <= set(dir(fabric))


def test02_paper_preset_matches_sec_5_1() -> None:
    cfg = fp.FabricGenParams(preset="paper").resolved()
    assert cfg.patterns == TRAINING_PATTERNS
    sets = fp.plan_sets(cfg)
    by_pattern = {p: sum(1 for s in sets if s[0] == p) for p in cfg.patterns}
    assert by_pattern["plain"] == 81
    assert all(n == 64 for p, n in by_pattern.items() if p != "plain")
    assert len(sets) == 81 + 192 + 192
    assert (cfg.queries, cfg.samples, cfg.sampler) == (3_276_800, 2048, "sobol")


def test03_explicit_fields_override_the_preset() -> None:
    cfg = fp.FabricGenParams(
        preset="paper", patterns=["satin_5x5"], texture_sets=2, shading_sets=3, samples=512
    ).resolved()
    assert cfg.patterns == ("satin_5x5",)
    assert fp.plan_sets(cfg) == [("satin_5x5", j, k) for j in range(2) for k in range(3)]
    assert cfg.samples == 512 and cfg.queries == 3_276_800 and cfg.map_resolution == 256


def test04_too_many_materials_is_rejected() -> None:
    with pytest.raises(ValidationError, match="at most 1000 materials"):
        fp.FabricGenParams(texture_sets=64, shading_sets=64)
