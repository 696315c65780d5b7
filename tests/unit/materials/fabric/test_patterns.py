"""Weave patterns as data, material parameters and sample points.

Oracles: textbook weave structure (a satin has one interlacing per row and column, a twill
shifts by one cell per row, floats of a k/(n-k) twill are k and n-k long), counting cells by
hand, the registry's validation errors, and the defining properties of the samplers
(points independent of chunking, each Sobol replicate a net: one point per 1/B stratum).
"""

from __future__ import annotations

import numpy as np
import pytest

from materials.fabric import samplers
from materials.fabric.params import PARAM_RANGES, FabricParams, YarnPair, sample_params
from materials.fabric.patterns import (
    PATTERNS,
    TRAINING_PATTERNS,
    UNSEEN_PATTERNS,
    Pattern,
    get_pattern,
    pattern_from_spec,
    pattern_registry,
    satin,
    twill,
)


def test01_builtins_are_the_papers_patterns() -> None:
    assert set(TRAINING_PATTERNS) | set(UNSEEN_PATTERNS) == set(PATTERNS)
    assert len(TRAINING_PATTERNS) == 7 and UNSEEN_PATTERNS == ("twill_4x4",)
    shapes = {name: p.shape for name, p in PATTERNS.items()}
    assert shapes["plain"] == (2, 2) and shapes["twill_8x8"] == (8, 8)
    assert shapes["satin_5x10"] == (5, 5)
    assert PATTERNS["satin_5x10"].tile_size == (5.0, 10.0)
    with pytest.raises(TypeError):
        PATTERNS["mine"] = PATTERNS["plain"]  # type: ignore[index]


@pytest.mark.parametrize("name", ["satin_5x5", "satin_8x8", "satin_5x10"])
def test02_satin_interlaces_once_per_row_and_column_never_adjacent(name: str) -> None:
    m = PATTERNS[name].warp_up
    n = m.shape[0]
    assert np.all((~m).sum(axis=0) == 1) and np.all((~m).sum(axis=1) == 1)
    rows, cols = np.nonzero(~m)
    for r, c in zip(rows, cols, strict=True):  # no two interlacings touch, even diagonally
        nxt = cols[(r + 1) % n == rows][0]
        assert min((nxt - c) % n, (c - nxt) % n) > 1
    offset, length = PATTERNS[name].float_tables()
    assert np.all(length[m] == n - 1) and np.all(length[~m] == 1)
    assert sorted(offset[:, 0][m[:, 0]]) == list(range(n - 1))


@pytest.mark.parametrize(
    ("name", "up"), [("twill_3x3", 2), ("twill_4x4", 2), ("twill_5x5", 3), ("twill_8x8", 4)]
)
def test03_twill_diagonal_and_floats(name: str, up: int) -> None:
    p = PATTERNS[name]
    m = p.warp_up
    n = m.shape[0]
    for i in range(n):
        np.testing.assert_array_equal(m[i], np.roll(m[0], i))
    _, length = p.float_tables()
    assert np.all(length[m] == up) and np.all(length[~m] == n - up)
    assert p.warp_fraction == pytest.approx(up / n)


def test03b_satin_5x10_is_the_5x5_on_tall_cells() -> None:
    """Sec. 5.1's satin 5x10: the 5x5 matrix on cells twice as tall, so the tile is 5 x 10
    and a warp float (4 cells along t) is 8 units long, a weft float 1 unit."""
    tall, square = PATTERNS["satin_5x10"], PATTERNS["satin_5x5"]
    np.testing.assert_array_equal(tall.warp_up, square.warp_up)
    assert tall.tile_size == (5.0, 10.0) and square.tile_size == (5.0, 5.0)
    _, length = tall.float_tables()
    m = tall.warp_up
    assert np.all(length[m] * tall.cell_size[1] == 8.0)
    assert np.all(length[~m] * tall.cell_size[0] == 1.0)


def test04_plain_and_float_tables() -> None:
    p = PATTERNS["plain"]
    offset, length = p.float_tables()
    assert np.all(length == 1) and np.all(offset == 0)
    # The warp/weft swap of a plain weave is a plain weave shifted by one cell.
    swapped = p.transposed("plain_swapped").warp_up
    np.testing.assert_array_equal(swapped, np.roll(p.warp_up, 1, axis=1))
    # A float wrapping around the tile edge: column 0 of this pattern is up in rows 3, 4, 0.
    wrap = Pattern.from_rows("wrap", ["10", "01", "01", "10", "10"])
    off, ln = wrap.float_tables()
    assert ln[0, 0] == ln[3, 0] == ln[4, 0] == 3
    assert (off[3, 0], off[4, 0], off[0, 0]) == (0, 1, 2)


def test05_user_patterns_are_validated() -> None:
    basket = pattern_from_spec({"name": "basket_2x2", "rows": ["1100", "1100", "0011", "0011"]})
    reg = pattern_registry([basket])
    assert get_pattern("basket_2x2", reg) is basket and "basket_2x2" not in PATTERNS
    with pytest.raises(ValueError, match="already registered"):
        pattern_registry([basket, basket])
    with pytest.raises(ValueError, match="already registered"):
        pattern_registry([Pattern.from_rows("plain", ["10", "01"])])
    with pytest.raises(ValueError, match="never interlace"):
        Pattern.from_rows("floating", ["11", "01"])  # warp 0 never goes under
    with pytest.raises(ValueError, match="never interlace"):
        Pattern.from_rows("floating", ["10", "10"])
    with pytest.raises(ValueError, match="unknown characters"):
        Pattern.from_rows("bad", ["1a", "01"])
    with pytest.raises(ValueError, match="pattern name"):
        Pattern.from_rows("Bad Name", ["10", "01"])
    with pytest.raises(ValueError, match="unknown pattern keys"):
        pattern_from_spec({"name": "x", "rows": ["10", "01"], "colour": 1})
    with pytest.raises(ValueError, match="unknown pattern"):
        get_pattern("velvet")
    with pytest.raises(ValueError):
        satin(6, 2)  # move not coprime with n
    with pytest.raises(ValueError):
        twill(4, 4)


def test06_params_validate_and_broadcast() -> None:
    p = FabricParams("twill_3x3", psi_deg=25.0, alpha=(0.2, 0.4), kd_warp=0.3)  # type: ignore[arg-type]
    assert p.psi_deg == YarnPair(25.0, 25.0) and p.alpha.weft == 0.4
    assert p.kd_warp == (0.3, 0.3, 0.3) and p.pattern is PATTERNS["twill_3x3"]
    assert p.albedos().shape == (4, 3)
    assert p.replace(w=0.1).w == 0.1
    with pytest.raises(ValueError, match="alpha"):
        FabricParams("plain", alpha=0.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="u_max_deg"):
        FabricParams("plain", u_max_deg=89.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="kd_weft"):
        FabricParams("plain", kd_weft=(0.2, 1.5, 0.1))  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    for name in TRAINING_PATTERNS:
        q = sample_params(rng, name)
        for field in ("psi_deg", "u_max_deg", "alpha", "beta"):
            r = PARAM_RANGES[field]
            assert all(r.sample_low <= v <= r.sample_high for v in getattr(q, field))
        assert q.gap == 0.2 and q.t_rho == 2.0


@pytest.mark.parametrize("sampler", ["independent", "sobol"])
def test07_points_do_not_depend_on_chunking(sampler: samplers.Sampler) -> None:
    kw = {"seed": 7, "samples": 64, "replicates": 4}
    whole = samplers.sample_points(sampler, first_query=0, n_queries=150, **kw)
    parts = [
        samplers.sample_points(sampler, first_query=a, n_queries=b - a, **kw)
        for a, b in ((0, 10), (10, 70), (70, 150))
    ]
    np.testing.assert_array_equal(whole, np.concatenate(parts))
    assert whole.dtype == np.float32 and whole.min() > 0 and whole.max() < 1
    other = samplers.sample_points(sampler, first_query=0, n_queries=150, **{**kw, "seed": 8})
    assert not np.array_equal(whole, other)


def test08_sobol_replicates_are_stratified_nets() -> None:
    pts = samplers.sample_points(
        "sobol", seed=3, first_query=5, n_queries=3, samples=256, replicates=4
    ).reshape(3, 4, 64, 3)
    for q in range(3):
        for r in range(4):
            for d in range(3):  # every 1-D projection of a (t, m, s)-net is a (0, m, 1)-net
                strata = np.floor(pts[q, r, :, d] * 64).astype(int)
                assert sorted(strata) == list(range(64))
            # 2-D: the first two Sobol dimensions form a (0, m, 2)-net: one point per 8x8 cell.
            cells = np.floor(pts[q, r, :, 0] * 8).astype(int) * 8 + np.floor(
                pts[q, r, :, 1] * 8
            ).astype(int)
            assert sorted(cells) == list(range(64))
    with pytest.raises(ValueError, match="power of two"):
        samplers.check_sampling("sobol", 96, 4)
    with pytest.raises(ValueError, match="multiple"):
        samplers.check_sampling("independent", 10, 4)
