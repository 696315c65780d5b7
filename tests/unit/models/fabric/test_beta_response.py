"""``held_out_beta``'s pieces: the material match and the slopes of ``beta_response``.

References: numpy's own least-squares line (``np.polyfit``) for the slopes; the match
rule written out (warp and weft equal, within 1e-6 of a listed value).
"""

from __future__ import annotations

import numpy as np
import pytest

from jobapi.errors import JobFailed
from models.fabric.data import MaterialData
from models.fabric.report import held_out_materials, response_slope


def material(name: str, beta: tuple[float, float]) -> MaterialData:
    empty = np.zeros((0, 8), np.float32)
    return MaterialData(
        name=name,
        pattern="plain",
        record={"beta": list(beta)},
        maps=np.zeros((6, 2, 2), np.float32),
        params=np.zeros(5, np.float32),
        query=empty,
        value=np.zeros((0, 4), np.float32),
        train=np.arange(0),
        test=np.arange(0),
    )


def test01_slopes_match_numpys_least_squares_line() -> None:
    rng = np.random.default_rng(3)
    beta = np.array([0.1, 0.34, 0.58, 0.82, 1.0])
    mean = rng.normal(size=(5, 5)) + 2.0 * beta[:, None] * np.arange(5)
    want = [np.polyfit(beta, mean[:, k], 1)[0] for k in range(5)]
    np.testing.assert_allclose(response_slope(beta, mean), want, rtol=1e-10, atol=1e-12)
    # A falling response has a negative slope.
    assert response_slope(beta, -beta[:, None])[0] == pytest.approx(-1.0)


def test02_materials_match_by_beta_and_bad_values_fail() -> None:
    # 0.1 + 0.9 * 2 / 3 is 0.7000000000000001 in float64: within the match tolerance.
    mats = [
        material("a", (0.1, 0.1)),
        material("b", (0.1 + 0.9 * 2 / 3, 0.1 + 0.9 * 2 / 3)),
        material("c", (0.7, 0.4)),  # warp and weft differ: never held out
        material("d", (1.0, 1.0)),
    ]
    assert held_out_materials(mats, [0.7]) == [1]
    assert held_out_materials(mats, [0.7, 1.0]) == [1, 3]
    with pytest.raises(JobFailed, match="held_out_beta: no material .* beta 0.5"):
        held_out_materials(mats, [0.5])
    with pytest.raises(JobFailed, match="every material"):
        held_out_materials(mats[:2], [0.1, 0.7])
