"""``preview.png`` of a BTF (:mod:`generators.btf.preview`): the unfolded BRDF's axes are
labelled with the directions' angles (they were the indices 0-5), at most
:data:`~generators.btf.preview.MAX_TICKS` of them; the reference is each direction's own
angles, built here from polar and azimuth angles in degrees."""

from __future__ import annotations

import numpy as np

from generators.btf.preview import MAX_TICKS, direction_ticks, preview_png
from materials.btf.directions import ubo2014_directions


def direction(theta: float, phi: float) -> list[float]:
    t, p = np.radians(theta), np.radians(phi)
    return [np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)]


def test01_ticks_are_the_directions_angles_in_order_of_appearance() -> None:
    # each light direction repeated for 3 views, as a BTF's slices are ordered
    lights = [(0, 0), (30, 90), (60, 180)]
    wi = np.array([direction(t, p) for t, p in lights for _ in range(3)])
    at, labels = direction_ticks(wi)
    assert at == [0, 1, 2]
    assert labels == ["0°/0°", "30°/90°", "60°/180°"]


def test02_many_directions_get_at_most_max_ticks() -> None:
    at, labels = direction_ticks(ubo2014_directions())
    assert len(at) == len(labels) <= MAX_TICKS and at[0] == 0 and at[-1] == 150
    assert all("°/" in label for label in labels)


def test03_the_figure_is_drawn() -> None:
    wi = np.array([direction(t, p) for t, p in [(0, 0), (30, 90)] for _ in range(2)])
    wo = np.array([direction(t, p) for _ in range(2) for t, p in [(10, 0), (45, 270)]])
    slices = [(i, np.full((4, 4, 3), 0.1 * (i + 1))) for i in range(4)]
    png = preview_png(slices, wi, wo, np.full((4, 3), 0.2), (0, 0), "test")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
