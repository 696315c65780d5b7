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
