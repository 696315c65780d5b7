"""The ``unseen_small``, ``unseen`` and ``unseen_paper`` presets of ``generate.fabric``: the
paper's shape (Sec. 5.1: the seven training patterns, texture x shading sets, every material
its own draw of Table 1's parameters) with held-out sets. References: Sec. 5.1's counts
(9 x 9 plain, 4 x 16 for each twill and satin: 465), Fig. 5's unseen twill 4x4, and the
split rule of :func:`generators.fabric.params.material_split` stated in its docstring."""

from __future__ import annotations

import hashlib
from collections import Counter

import numpy as np
import pytest
from pydantic import ValidationError

from generators.fabric.kind import plan_materials
from generators.fabric.params import FabricGenParams, material_split, plan_sets
from materials.fabric.patterns import TRAINING_PATTERNS, UNSEEN_PATTERNS
from storage.formats.fabric_documents import FABRIC_SPLITS


class _Ctx:
    """The two JobContext methods plan_materials uses, seeded by name."""

    def rng(self, name: str) -> np.random.Generator:
        return np.random.default_rng(int.from_bytes(hashlib.sha256(name.encode()).digest()[:8]))

    def sub_seed(self, name: str) -> int:
        return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def test01_split_rule() -> None:
    assert FABRIC_SPLITS == ("train", "unseen_material", "unseen_pattern")
    assert UNSEEN_PATTERNS == ("twill_4x4",)
    assert material_split("twill_4x4", 0, 4) == "unseen_pattern"
    assert material_split("twill_4x4", 3, 4) == "unseen_pattern"
    assert material_split("plain", 3, 4) == "unseen_material"
    assert [material_split("satin_5x10", k, 4) for k in range(3)] == ["train"] * 3
    assert material_split("plain", 0, 1) == "train"  # one shading set: nothing held out


def test02_machine_size_counts() -> None:
    cfg = FabricGenParams(preset="unseen").resolved()
    assert cfg.patterns == (*TRAINING_PATTERNS, "twill_4x4") and cfg.splits
    sets = plan_sets(cfg)
    assert len(sets) == 7 * 4 * 4 + 2 * 2 == 116
    splits = Counter(material_split(p, k, cfg.shading_sets[p]) for p, _, k in sets)
    assert splits == {"train": 84, "unseen_material": 28, "unseen_pattern": 4}
    assert (cfg.queries, cfg.samples, cfg.sizes) == (20_480, 256, "strata")
    assert cfg.queries % 20_480 == 0  # complete rounds of every stratum


def test03_paper_size_is_sec_5_1_plus_the_unseen_twill() -> None:
    cfg = FabricGenParams(preset="unseen_paper").resolved()
    sets = plan_sets(cfg)
    seen = Counter(p for p, _, _ in sets if p in TRAINING_PATTERNS)
    assert seen["plain"] == 81 and sum(seen.values()) == 465
    assert all(n == 64 for p, n in seen.items() if p != "plain")
    assert sum(1 for p, _, _ in sets if p == "twill_4x4") == 16
    assert (cfg.queries, cfg.samples, cfg.sizes) == (3_276_800, 2048, "strata")


def test04_sizes_and_splits_resolve() -> None:
    unseen = FabricGenParams(preset="unseen", sizes="log_uniform").resolved()
    assert unseen.sizes == "log_uniform" and unseen.splits
    scene = {"name": "cloth_plane", "resolution": [16, 16]}
    assert FabricGenParams(preset="unseen_small", scene=scene).resolved().splits
    with pytest.raises(ValidationError, match="sizes: leave it out with scene"):
        FabricGenParams(preset="unseen_small", sizes="log_uniform", scene=scene)
    assert not FabricGenParams(preset="small").resolved().splits
    assert not FabricGenParams(preset="paper").resolved().splits


def test05_every_material_its_own_draw_of_table_1() -> None:
    """Beta, alpha, w and the albedos vary from material to material within a pattern; the
    yarn geometry (psi, u) per texture set; splits follow the rule."""
    cfg = FabricGenParams(preset="unseen", patterns=["twill_5x5", "twill_4x4"]).resolved()
    plan = plan_materials(cfg, _Ctx())  # type: ignore[arg-type]
    for pattern in ("twill_5x5", "twill_4x4"):
        mats = [m for m in plan if m.pattern == pattern]
        for attr in ("beta", "alpha", "w", "kd_warp"):
            # continuous draws: a tie has probability 0
            assert len({getattr(m.params, attr) for m in mats}) == len(mats), attr
        geometry = {(m.texture_set, m.params.psi_deg, m.params.u_max_deg) for m in mats}
        assert len(geometry) == cfg.texture_sets[pattern]
    assert {m.split for m in plan if m.pattern == "twill_4x4"} == {"unseen_pattern"}
    held = [m.shading_set for m in plan if m.split == "unseen_material"]
    assert held == [3] * 4
    assert all(m.split is None for m in plan_materials(
        FabricGenParams(preset="small").resolved(), _Ctx()  # type: ignore[arg-type]
    ))  # fmt: skip
