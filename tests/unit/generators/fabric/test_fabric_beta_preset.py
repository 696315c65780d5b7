"""The ``beta`` preset of ``generate.fabric``: per pattern >= 16 materials that differ only in
beta, spanning Sec. 5.1's range 0.1-1 (ends included), everything Eq. 7 leaves out (w, the
albedos) and the rest of the material held. Reference: the paper's sampling range and the
definition of an even grid (closed form ``0.1 + 0.9 k / (n - 1)``)."""

from __future__ import annotations

import hashlib
from dataclasses import fields

import numpy as np

from generators.fabric.kind import plan_materials
from generators.fabric.params import BETA_SWEEP, FabricGenParams


class _Ctx:
    """The two JobContext methods plan_materials uses, seeded by name."""

    def rng(self, name: str) -> np.random.Generator:
        return np.random.default_rng(int.from_bytes(hashlib.sha256(name.encode()).digest()[:8]))

    def sub_seed(self, name: str) -> int:
        return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


def test01_beta_preset_varies_beta_alone_over_its_range() -> None:
    cfg = FabricGenParams(preset="beta").resolved()
    plan = plan_materials(cfg, _Ctx())  # type: ignore[arg-type]
    assert BETA_SWEEP == (0.1, 1.0)  # Sec. 5.1: beta U(0.1, 1.0)
    for pattern in cfg.patterns:
        mats = [m.params for m in plan if m.pattern == pattern]
        assert len(mats) >= 16
        betas = np.array([p.beta.warp for p in mats])
        assert all(p.beta.weft == p.beta.warp for p in mats)
        ref = 0.1 + 0.9 * np.arange(len(mats)) / (len(mats) - 1)
        np.testing.assert_allclose(betas, ref, rtol=0, atol=1e-12)  # same closed form
        first = mats[0]
        for p in mats[1:]:
            for f in fields(p):
                if f.name != "beta":
                    assert getattr(p, f.name) == getattr(first, f.name), f.name


def test02_other_presets_still_draw_beta() -> None:
    cfg = FabricGenParams(preset="small", shading_sets=3).resolved()
    assert not cfg.beta_sweep
    plan = plan_materials(cfg, _Ctx())  # type: ignore[arg-type]
    betas = {m.params.beta for m in plan if m.pattern == "plain"}
    assert len(betas) == 3  # independent draws (continuous: a tie has probability 0)


def test03_beta_preset_materials_share_one_query_set() -> None:
    """Every beta of a texture set is estimated at the same queries with the same footprint
    samples (paired differences); the query set is named by pattern and texture set."""
    cfg = FabricGenParams(preset="beta", texture_sets=2).resolved()
    plan = plan_materials(cfg, _Ctx())  # type: ignore[arg-type]
    ctx = _Ctx()
    for pattern in cfg.patterns:
        for j in range(2):
            mats = [m for m in plan if m.pattern == pattern and m.texture_set == j]
            assert len(mats) == 16
            assert {m.query_set for m in mats} == {f"{pattern}-t{j:02d}"}
            assert {m.design_seed for m in mats} == {
                ctx.sub_seed(f"generate.fabric/queries/{pattern}-t{j:02d}")
            }
    # Two texture sets of a pattern, or two patterns, still have their own queries.
    assert len({m.design_seed for m in plan}) == 2 * len(cfg.patterns)


def test04_other_presets_keep_one_query_set_per_material() -> None:
    """The ``small`` and ``paper`` presets keep the seeds they had before the ``beta`` preset
    shared its query sets: keyed by the material's own name (so their bytes are unchanged)."""
    ctx = _Ctx()
    for preset in ("small", "paper"):
        cfg = FabricGenParams(preset=preset).resolved()
        plan = plan_materials(cfg, ctx)  # type: ignore[arg-type]
        for m in plan:
            assert m.query_set == m.name
            assert m.design_seed == ctx.sub_seed(f"generate.fabric/queries/{m.name}")
        assert len({m.design_seed for m in plan}) == len(plan)
