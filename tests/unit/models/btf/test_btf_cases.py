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
