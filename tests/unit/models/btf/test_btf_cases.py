"""The BTF failure cases (:mod:`models.btf.cases`) against directions whose angles are
known by construction: the reference is the geometry, not the code's own formulas."""

from __future__ import annotations

import numpy as np
import pytest

from materials.btf.directions import to_vector
from models.btf.cases import CASES, case_errors, case_masks


def test_masks_of_hand_built_directions() -> None:
    n = [0.0, 0.0, 1.0]
    # light 60 deg / view its mirror: shadowing and specular (half vector = the normal)
    # light = view = normal: specular only; light 30 deg, view normal: half vector at
    # 15 deg, neither; light 55 deg, view 55 deg same side: shadowing only (h at 55 deg)
    wi = np.vstack([to_vector([60, 0, 30, 55], [0, 0, 0, 90]), to_vector(80, 45)])
    wo = np.vstack([to_vector([60, 0, 0, 55], [180, 0, 0, 90]), [n]])
    m = case_masks(wi, wo)
    assert list(m) == list(CASES)
    assert m["shadowing"].tolist() == [True, False, False, True, True]
    assert m["specular"].tolist() == [True, True, False, False, False]
    assert m["rest"].tolist() == [False, False, True, False, False]


def test_case_errors_are_means_over_their_slices() -> None:
    rng = np.random.default_rng(3)
    theta_i, theta_o = rng.uniform(0, 85, 200), rng.uniform(0, 85, 200)
    wi = to_vector(theta_i, rng.uniform(0, 360, 200))
    wo = to_vector(theta_o, rng.uniform(0, 360, 200))
    l1, scale = rng.uniform(0.0, 1.0, 200), rng.uniform(0.5, 2.0, 200)
    out = {c["case"]: c for c in case_errors(wi, wo, l1, scale)}
    shadow = theta_i >= 50.0  # the light's polar angle, as drawn
    assert out["shadowing"]["slices"] == int(shadow.sum())
    assert out["shadowing"]["l1"] == pytest.approx(l1[shadow].mean(), rel=1e-12)
    rest = case_masks(wi, wo)["rest"]
    assert out["rest"]["relative_l1"] == pytest.approx(l1[rest].mean() / scale[rest].mean())
    # rest is the complement of the union
    union = case_masks(wi, wo)["shadowing"] | case_masks(wi, wo)["specular"]
    assert out["rest"]["slices"] + int(union.sum()) == 200
    # an empty case reports None, not a NaN
    none = {c["case"]: c for c in case_errors(wi[:0], wo[:0], l1[:0], scale[:0])}
    assert none["specular"] == {**none["specular"], "slices": 0, "l1": None, "relative_l1": None}


class _Slices:
    """A stand-in for a BtfDataset: slices in memory, directions unused by the predictors."""

    def __init__(self, slices: np.ndarray) -> None:
        self.slices = slices
        self.resolution = slices.shape[1:3]
        self.wi = self.wo = np.zeros((len(slices), 3), np.float32)

    def iter_slices(self, indices: np.ndarray):  # type: ignore[no-untyped-def]
        for i in indices:
            yield int(i), self.slices[int(i)]


def test_fine_detail_case_against_hand_built_slices() -> None:
    """References by construction: a block-constant model drops all the detail (relative 1),
    the truth itself none (0), a block-constant offset leaves the detail alone (0); one
    hand-computed 2 x 2 block."""
    from models.btf.cases import DETAIL_CASE, block_detail, detail_slices, fine_detail_error

    rng = np.random.default_rng(7)
    truth = rng.uniform(0.0, 1.0, (5, 4, 6, 3)).astype(np.float32)
    data = _Slices(truth)
    idx = np.arange(5)

    def blocky(i: int) -> np.ndarray:
        t = truth[i].astype(np.float64)
        return t - block_detail(t)

    it = iter(range(5))
    flat = fine_detail_error(lambda wi, wo: blocky(next(it)), data, idx)
    assert flat["case"] == DETAIL_CASE and flat["slices"] == 5
    assert flat["relative_l1"] == pytest.approx(1.0, rel=1e-12)
    it = iter(range(5))
    same = fine_detail_error(lambda wi, wo: truth[next(it)], data, idx)
    assert same["l1"] == 0.0 and same["relative_l1"] == 0.0
    offset = np.kron(rng.normal(size=(2, 3)), np.ones((2, 2)))[..., None]
    it = iter(range(5))
    shifted = fine_detail_error(lambda wi, wo: truth[next(it)] + offset, data, idx)
    assert shifted["l1"] == pytest.approx(0.0, abs=1e-6)  # float32 truth + float64 offset
    # one block [[1, 2], [3, 6]] (mean 3) against a model [[0, 0], [0, 0]]: truth detail
    # -2, -1, 0, 3 and model detail 0: L1 = 6 / 4, relative 1
    one = _Slices(np.array([[[1.0], [2.0]], [[3.0], [6.0]]])[None])
    got = fine_detail_error(lambda wi, wo: np.zeros((2, 2, 1)), one, np.arange(1))
    assert got["l1"] == pytest.approx(1.5) and got["relative_l1"] == pytest.approx(1.0)
    # odd resolution or no slices: no figure, not a NaN
    odd = fine_detail_error(lambda wi, wo: truth[0], _Slices(truth[:, :3]), idx)
    assert odd["l1"] is None and odd["relative_l1"] is None
    assert detail_slices(10, np.array([3, 4])).tolist() == [3, 4]
    assert detail_slices(10_000, np.array([], np.int64)).size == 512
