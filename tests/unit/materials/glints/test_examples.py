"""Tiny examples: the conventions hold for every procedural type and size, examples are
seeded and tile; bad user maps are refused naming the file.

Oracles: the conventions themselves (unit length, z > 0, shape), byte equality for equal
seeds, and a tiling check against the example's own interior (the mean wrap-around step
between the last and first row or column is no larger than the steps inside).
"""

from __future__ import annotations

import numpy as np
import pytest

from materials.glints.examples import DEFAULT_SLOPE, SIZES, TYPES, procedural_example
from storage.errors import FormatError
from storage.formats.normal_map import check_normal_map, normals_from_rgb


@pytest.mark.parametrize("kind", TYPES)
def test01_conventions(kind: str) -> None:
    for size in (8, 32, 256):
        m = procedural_example(kind, size, np.random.default_rng(1))
        assert m.shape == (size, size, 3) and m.dtype == np.float32
        assert np.allclose(np.linalg.norm(m, axis=-1), 1.0, atol=1e-6)
        assert m[..., 2].min() > 0.0
        check_normal_map(m, f"{kind}-{size}")
        # The RMS slope of the height field is the type's target (normals = (-g, 1)/|.|).
        slope = np.sqrt(((m[..., :2] / m[..., 2:]) ** 2).sum(-1).mean())
        assert slope == pytest.approx(DEFAULT_SLOPE[kind], rel=1e-3)


@pytest.mark.parametrize("kind", TYPES)
def test02_seeded_and_tiling(kind: str) -> None:
    a = procedural_example(kind, 32, np.random.default_rng(7))
    b = procedural_example(kind, 32, np.random.default_rng(7))
    c = procedural_example(kind, 32, np.random.default_rng(8))
    assert a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    for axis in (0, 1):
        # Seamless: the step across the wrap is an ordinary step between neighbouring rows
        # (columns), no larger than the largest one inside.
        other = tuple(i for i in (0, 1, 2) if i != axis)
        steps = np.abs(np.diff(a[..., :2], axis=axis)).mean(axis=other[-1]).mean(axis=other[0])
        wrap = np.abs(np.take(a, 0, axis=axis) - np.take(a, -1, axis=axis))[..., :2].mean()
        assert wrap <= 1.5 * steps.max() + 1e-6, (kind, axis, wrap, steps.max())


def test03_sizes_and_types_are_checked() -> None:
    with pytest.raises(ValueError, match="size must be one of"):
        procedural_example("leather", 12, np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown example type"):
        procedural_example("wood", 16, np.random.default_rng(0))
    assert SIZES[0] == 8 and SIZES[-1] == 256


def _flat(n: int) -> np.ndarray:
    m = np.zeros((n, n, 3), np.float32)
    m[..., 2] = 1.0
    return m


@pytest.mark.parametrize(
    ("normals", "what"),
    [
        (_flat(8)[:, :4], "must be square"),
        (np.tile(_flat(6), (1, 1, 1)), "power of two"),
        (_flat(8) * 1.1, "unit length"),
        (-_flat(8), "point up"),
        (np.full((8, 8, 3), np.nan, np.float32), "NaN"),
        (np.zeros((8, 8), np.float32), r"shape \(n, n, 3\)"),
    ],
)
def test04_bad_maps_are_refused_naming_the_file(normals: np.ndarray, what: str) -> None:
    with pytest.raises(FormatError, match=what) as err:
        check_normal_map(normals, "mine.normal.exr")
    assert "mine.normal.exr" in str(err.value)


def test05_png_encoding_round_trip() -> None:
    """An 8-bit ``(n + 1) / 2`` map decodes to unit normals within the quantisation step."""
    m = procedural_example("leather", 16, np.random.default_rng(2))
    rgb = np.round((m + 1.0) / 2.0 * 255.0) / 255.0
    back = normals_from_rgb(rgb, "x.normal.png", encoded=True)
    assert np.abs(back - m).max() < 2.0 / 255.0
    with pytest.raises(FormatError, match="unit length"):
        normals_from_rgb(rgb, "x.normal.exr", encoded=False)
